"""scripts/slam_edge_diagnosis.py: the edge errors it reports and the true measurements it
swaps in are the ones the pose graph sees."""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np

from sage_robot.core.geometry import relative
from sage_robot.nav.slam.posegraph import KIND_SCAN, PoseGraph
from tests.slam.scripts import load_script


def load() -> ModuleType:
    return load_script("slam_edge_diagnosis")


def test_the_error_is_the_one_the_graph_weighs() -> None:
    diag = load()
    g = PoseGraph()
    g.add_node((0.0, 0.0, 0.3))
    g.add_node((1.0, 0.5, 1.2))
    z = (0.9, 0.7, 0.85)
    info = np.diag([4.0, 9.0, 25.0])
    g.add_edge(0, 1, z, info, KIND_SCAN)
    truth = g.poses
    err = diag.error_at(z, relative(truth[0], truth[1]))
    chi = float(np.sqrt(err @ info @ err))
    assert math.isclose(chi, float(g.edge_errors()[0]), rel_tol=1e-9)


def test_a_true_component_swapped_in_leaves_the_others() -> None:
    diag = load()
    zt = (1.0, 0.2, 0.4)
    z = (1.05, 0.17, 0.43)
    before = diag.components(diag.error_at(z, zt), diag.travel_axis(z))
    for k, part in enumerate(diag.COMPONENTS):
        edge = _Edge(z)
        fixed = diag.with_true(part)(edge, zt)
        # split on the travel axis of the measurement it replaced
        after = diag.components(diag.error_at(fixed, zt), diag.travel_axis(z))
        assert abs(after[k]) < 1e-12
        assert all(math.isclose(after[o], before[o], abs_tol=1e-12) for o in range(3) if o != k)
    assert np.allclose(diag.with_true(None)(_Edge(z), zt), zt)


def test_the_information_turns_with_the_heading() -> None:
    diag = load()
    corridor_north = np.diag([1e4, 1.0, 1e5])  # map frame: pinned east-west, free north-south
    turned = diag.in_edge_frame(corridor_north, math.pi / 2)  # driving north: x is forward
    assert np.allclose(np.diag(turned), [1.0, 1e4, 1e5])


class _Edge:
    def __init__(self, z: tuple[float, float, float]) -> None:
        self.z = z
