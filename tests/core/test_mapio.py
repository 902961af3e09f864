import math

import numpy as np
import pytest

from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import cell_to_world, read_map, world_to_cell, write_map
from sage_robot.core.msgs import Pose2D

from ..support.grids import blank, grid_of

REAL_MAPS = [
    ("maps/willow-2010-02-18/willow-2010-02-18-0.10.yaml", (608, 566), 0.10),
    ("maps/willow-full/willow-full.yaml", (587, 540), 0.10),
    ("maps/nav2-depot/depot.yaml", (307, 604), 0.05),
    ("maps/nav2-warehouse/warehouse.yaml", (1674, 1006), 0.03),
    ("maps/tb3-sandbox/tb3_sandbox.yaml", (384, 384), 0.05),
]


@pytest.mark.parametrize(("rel", "shape", "res"), REAL_MAPS, ids=lambda v: str(v)[:30])
def test_real_maps_load(shared_data, rel, shape, res):
    grid = read_map(shared_data(rel))
    assert grid.data.shape == shape
    assert grid.resolution == pytest.approx(res)
    values = set(np.unique(grid.data).tolist())
    assert values <= {-1, 0, 100}
    assert {0, 100} <= values


def test_seed_style_free_thresh_and_flip(tmp_path):
    # A 3x2 image: top row black (wall), middle light grey (205), bottom white.
    from PIL import Image

    Image.fromarray(np.array([[0, 0], [205, 205], [254, 254]], dtype=np.uint8)).save(tmp_path / "m.pgm")
    (tmp_path / "m.yaml").write_text(
        "image: m.pgm\nresolution: 0.05\norigin: [-1.0, -2.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.1\n"
    )
    grid = read_map(tmp_path / "m.yaml")
    # row 0 is the bottom of the image (origin side)
    assert grid.data[:, 0].tolist() == [0, -1, 100]
    assert grid.origin == Pose2D(-1.0, -2.0, 0.0)


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(3)
    data = rng.choice(np.array([-1, 0, 100], dtype=np.int8), size=(40, 70))
    grid = grid_of(data, 0.05, (1.5, -2.25))
    back = read_map(write_map(grid, tmp_path / "out.yaml", free_thresh=0.1))
    assert np.array_equal(back.data, data)
    assert back.origin == grid.origin
    assert back.resolution == grid.resolution


def test_transforms_with_rotated_origin():
    grid = blank(10, 20, 0.1, (2.0, 1.0), theta=math.pi / 2)
    x, y = cell_to_world(grid, 3, 5)  # cell centre at grid (0.55, 0.35) → rotated 90°
    assert (float(x), float(y)) == pytest.approx((2.0 - 0.35, 1.0 + 0.55))
    r, c = world_to_cell(grid, x, y)
    assert (int(r), int(c)) == (3, 5)


def test_bad_map_files_name_the_problem(tmp_path):
    (tmp_path / "a.yaml").write_text("image: nope.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(ConfigError, match=r"image .*nope\.pgm not found"):
        read_map(tmp_path / "a.yaml")
    (tmp_path / "b.yaml").write_text("image: x.pgm\nresolution: 0.05\norigin: [0, 0]\n")
    with pytest.raises(ConfigError, match=r"origin: expected \[x, y, yaw\]"):
        read_map(tmp_path / "b.yaml")
    (tmp_path / "c.yaml").write_text("image: x.pgm\norigin: [0, 0, 0]\n")
    with pytest.raises(ConfigError, match="missing key 'resolution'"):
        read_map(tmp_path / "c.yaml")
