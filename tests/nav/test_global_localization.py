"""Global localization: where it searches, multi-hypothesis reporting, look-alike places,
and convergence in the default building's repetitive corridors."""

from __future__ import annotations

import math

import numpy as np

from sage_robot.core.config import Settings
from sage_robot.core.geometry import wrap_angle
from sage_robot.nav.amcl import ParticleFilter
from sage_robot.nav.amcl_global import KEEP_SHARE, hypotheses, keep_alive, search_region
from sage_robot.nav.mapdata import load_for

from ..support.grids import draw
from .nav_raycast import RANGE_MAX_M, beam_angles, cast

SENSOR = (0.0, 0.0, 0.0)
STEP_M = 0.25  # one filter update per AMCL update_min_d

# A building drawn inside free space (the shipped map's grey surround reads as free too).
BUILDING_IN_FREE = """
..............
.############.
.#..........#.
.#..........#.
.#..........#.
.############.
..............
"""

# Point-symmetric about its centre: (x, y, θ) and (12 - x, 6 - y, θ + π) see the same scan.
SYMMETRIC = """
########################
#......................#
#......................#
#....##................#
#....##................#
#......................#
#......................#
#................##....#
#................##....#
#......................#
#......................#
########################
"""


def _scan(grid, pose) -> tuple[np.ndarray, np.ndarray, float]:
    ang = beam_angles(180)
    return ang, cast(grid, pose, ang), RANGE_MAX_M


def test_search_region_keeps_to_the_free_space_that_holds_the_places() -> None:
    grid = draw(BUILDING_IN_FREE, 0.05, scale=10)  # 7 m × 3.5 m, 0.5 m per character
    pf = ParticleFilter(grid, np.random.default_rng(0), 100, 200, SENSOR, seeds=[(3.5, 1.75)])
    cells = pf.region
    x = (cells[:, 1] + 0.5) * 0.05
    y = (cells[:, 0] + 0.5) * 0.05
    assert len(cells) > 0
    assert x.min() > 1.0
    assert x.max() < 6.0
    assert y.min() > 1.0
    assert y.max() < 2.5  # inside the walls
    assert pf.field.dist[cells[:, 0], cells[:, 1]].min() >= 0.2  # never against a wall
    everywhere = search_region(pf.field)  # no places: all clear free space, outside included
    assert len(everywhere) > 2 * len(cells)
    poses = pf.random_poses(500)
    assert ((poses[:, 0] > 1.0) & (poses[:, 0] < 6.0)).all()


def test_hypotheses_count_the_places_a_cloud_considers() -> None:
    rng = np.random.default_rng(1)
    a = np.column_stack([rng.normal(2.0, 0.2, 600), rng.normal(2.0, 0.2, 600), np.zeros(600)])
    b = np.column_stack([rng.normal(20.0, 0.2, 400), rng.normal(9.0, 0.2, 400), np.zeros(400)])
    stray = np.column_stack([rng.uniform(0, 40, 10), rng.uniform(30, 60, 10), np.zeros(10)])
    cloud = np.vstack([a, b, stray])
    w = np.full(len(cloud), 1.0 / len(cloud))
    h = hypotheses(cloud, w)
    assert len(h) == 2  # the ten strays form none
    assert (round(h[0].x), round(h[0].y)) == (2, 2)
    assert (round(h[1].x), round(h[1].y)) == (20, 9)
    assert 0.55 < h[0].share < 0.62
    assert 0.36 < h[1].share < 0.42
    assert len(hypotheses(a, np.full(600, 1 / 600))) == 1


def test_twins_crossing_the_same_spot_facing_opposite_ways_stay_two_hypotheses() -> None:
    rng = np.random.default_rng(2)
    def cloud_at(x: float, heading: float, n: int) -> np.ndarray:
        return np.column_stack([rng.normal(x, 0.2, n), rng.normal(5.0, 0.2, n), rng.normal(heading, 0.05, n)])

    east, west = cloud_at(5.0, 0.0, 700), cloud_at(5.3, math.pi, 300)
    cloud = np.vstack([east, west])
    h = hypotheses(cloud, np.full(1000, 1e-3))
    assert [round(x.share, 1) for x in h] == [0.7, 0.3]


def _two_places(n_leader: int, n_runner: int) -> np.ndarray:
    rng = np.random.default_rng(4)
    a = np.column_stack([rng.normal(2.0, 0.1, n_leader), rng.normal(2.0, 0.1, n_leader), np.zeros(n_leader)])
    b = np.column_stack([rng.normal(30.0, 0.1, n_runner), rng.normal(2.0, 0.1, n_runner), np.zeros(n_runner)])
    return np.vstack([a, b])


def test_keep_alive_holds_a_look_alike_that_fits_as_well_and_drops_one_that_does_not() -> None:
    cloud = _two_places(1900, 100)
    w = np.concatenate([np.full(1900, 1.0), np.full(100, 1e-7)])  # runner-up's share: ~5e-9
    w /= w.sum()
    runner = np.arange(2000) >= 1900
    same_fit = np.full(2000, -0.5)  # log-likelihood per beam
    q, boost = keep_alive(cloud, w, same_fit)
    assert q[runner].sum() >= 0.99 * KEEP_SHARE  # still drawn: 5 % of the new particles
    kept = w * boost
    assert kept[runner].sum() / kept.sum() >= 1e-3  # and held at a share that still counts
    worse_fit = np.where(runner, -0.8, -0.5)
    q, boost = keep_alive(cloud, w, worse_fit)
    assert q[runner].sum() < 1e-6
    assert np.allclose(boost, 1.0)  # ruled out: let go
    q, boost = keep_alive(cloud, np.where(runner, 0.2, 1.0) / 400.0)  # a real runner-up (~1 %)
    assert q[runner].sum() >= 0.99 * KEEP_SHARE
    assert np.allclose(boost, 1.0)


def test_keep_alive_never_starves_the_leader_among_many_look_alikes() -> None:
    rng = np.random.default_rng(6)
    places = [np.column_stack([rng.normal(3.0 * k, 0.1, 100), rng.normal(1.0, 0.1, 100), np.zeros(100)])
              for k in range(20)]
    cloud = np.vstack(places)
    # a leader, five strong runner-ups and fourteen weak ones that the floor tops up
    w = np.concatenate([np.full(100, 0.3 / 100)] + [np.full(100, 0.13 / 100)] * 5
                       + [np.full(100, 0.05 / 14 / 100)] * 14)
    q, _ = keep_alive(cloud, w)
    assert q[:100].sum() >= 0.5 * 0.3  # the leader keeps at least half its share of the draws


def test_look_alike_places_stay_ambiguous_instead_of_converging_wrongly() -> None:
    grid = draw(SYMMETRIC, 0.05, scale=10)
    rng = np.random.default_rng(5)
    pf = ParticleFilter(grid, rng, 500, 2000, SENSOR, global_particles=4000)
    truth = (2.0, 1.25, 0.0)
    pf.global_localization(_scan(grid, truth))
    assert pf.count == 4000
    pf.update(truth, *_scan(grid, truth))  # odometry reference
    for _ in range(10):  # 2.5 m east: nothing tells the two halves apart
        truth = (truth[0] + STEP_M, truth[1], 0.0)
        pf.update(truth, *_scan(grid, truth), force=True)
    mirror = (12.0 - truth[0], 6.0 - truth[1])
    h = pf.hypotheses()
    assert len(h) >= 2
    assert min(math.hypot(x.x - truth[0], x.y - truth[1]) for x in h) < 0.3
    assert min(math.hypot(x.x - mirror[0], x.y - mirror[1]) for x in h) < 0.3
    # reported as far from converged (the distance between the two), though each part is tight
    assert pf.spread_m() > 0.9 * math.hypot(mirror[0] - truth[0], mirror[1] - truth[1])


def test_global_localization_in_the_default_building_converges_along_a_corridor() -> None:
    settings = Settings()
    data = load_for(settings)
    seeds = [(p.pose.x, p.pose.y) for p in data.places]
    pf = ParticleFilter(data.grid, np.random.default_rng(0), 500, 2000, SENSOR, seeds=seeds)
    # the east-west corridor, heading west: labs of one size on both sides
    truth = (84.5, 39.8, math.pi)
    assert pf.field.distances(np.linspace(70.0, 85.0, 50), np.full(50, 39.8)).min() > 0.5
    region_m2 = len(pf.region) * data.grid.resolution**2
    assert 1000 < region_m2 < len(pf.field.free_cells) * data.grid.resolution**2
    assert (data.grid.data[pf.region[:, 0], pf.region[:, 1]] == 0).all()  # known floor, not the outside
    assert (data.grid.data == -1).sum() > (data.grid.data == 0).sum()  # the outside loads as unknown
    pf.global_localization(_scan(data.grid, truth))
    pf.update(truth, *_scan(data.grid, truth))
    errors = []
    for _ in range(40):  # at most 10 m of driving
        truth = (truth[0] - STEP_M, truth[1], math.pi)
        pf.update(truth, *_scan(data.grid, truth), force=True)
        e = pf.estimate()
        errors.append((math.hypot(e.x - truth[0], e.y - truth[1]), abs(wrap_angle(e.theta - truth[2]))))
    assert max(d for d, _ in errors[-10:]) < 0.3
    assert max(a for _, a in errors[-10:]) < 0.1
    assert len(pf.hypotheses()) == 1
    assert pf.spread_m() < 0.5
    assert pf.count <= 2000  # the raised global cap has come back down
