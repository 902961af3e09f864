"""The default building: deterministic, all 16 places valid, reachable and named as people say them."""

from __future__ import annotations

import filecmp
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from scipy import ndimage

from sage_robot.core.config import load_profile
from sage_robot.core.mapio import FREE, world_to_cell
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.core.paths import map_yaml, package_data, waypoints_yaml
from sage_robot.core.places import load_places, validate_places
from sage_robot.sim.building import build_lanes
from sage_robot.sim.scenario import low_obstacle
from sage_robot.sim.world import _box_distance

REPO = Path(__file__).resolve().parents[2]
SEED_PLACES = {
    "BIO_ENG_LAB", "SENIOR_DESIGN", "GUELLY_DELLY", "MANUFACTURING_LAB", "3D_PRINTING_LAB", "CLEAN_ROOM",
    "ECE_LAB_1", "ECE_LAB_2", "MECHATRONICS_LAB", "VALPO_ROBOTICS", "HESSE_CENTER", "BATHROOMS",
    "MATERIALS_TESTING_LAB", "HEAT_POWER_LAB", "TRANSPORTATION_LAB", "DOCKING_STATION",
}  # fmt: skip
ROBOT_RADIUS_M = 0.25
INFLATION_M = 0.55


def test_generator_is_deterministic(tmp_path: Path) -> None:
    subprocess.run([sys.executable, str(REPO / "scripts" / "generate_building.py"), str(tmp_path)],
                   check=True, capture_output=True, timeout=120)  # fmt: skip
    shipped = package_data("maps", "campus")
    for name in ("map.yaml", "map.pgm", "waypoints.yaml", "world.yaml"):
        assert filecmp.cmp(tmp_path / name, shipped / name, shallow=False), f"{name} differs"


def test_the_profile_points_at_the_shipped_building(campus_grid: OccupancyGrid) -> None:
    settings = load_profile(None)
    assert map_yaml(settings) == package_data("maps", "campus", "map.yaml")
    assert campus_grid.resolution == 0.05
    assert (campus_grid.width, campus_grid.height) == (2000, 1600)
    assert waypoints_yaml(settings).exists()


def test_all_seed_places_with_descriptions_validate(campus_grid: OccupancyGrid) -> None:
    places = load_places(package_data("maps", "campus", "waypoints.yaml"))
    assert set(places.names()) == SEED_PLACES
    for p in places:
        assert p.description, p.name
        assert p.aliases, p.name
        assert p.dwell_text, p.name
    validate_places(places, campus_grid)  # raises naming the place on a wall or outside


def test_spoken_names_resolve() -> None:
    places = load_places(package_data("maps", "campus", "waypoints.yaml"))
    spoken = {
        "the cafe": "GUELLY_DELLY", "Guelly Delly": "GUELLY_DELLY", "the deli": "GUELLY_DELLY",
        "3D printing lab": "3D_PRINTING_LAB", "three d printing": "3D_PRINTING_LAB",
        "the bathroom": "BATHROOMS", "ECE lab two": "ECE_LAB_2", "Hesse Center": "HESSE_CENTER",
        "docking station": "DOCKING_STATION", "valpo robotics": "VALPO_ROBOTICS",
    }  # fmt: skip
    for text, name in spoken.items():
        found = places.resolve(text)
        assert found is not None, text
        assert found.name == name, text


def test_corridors_are_as_long_and_wide_as_the_seeds() -> None:
    lanes = yaml.safe_load(package_data("maps", "campus", "world.yaml").read_text())["lanes"]
    nodes = np.array(lanes["nodes"])
    xs = nodes[np.isclose(nodes[:, 1], 40.0)][:, 0]
    ys = nodes[np.isclose(nodes[:, 0], 50.0)][:, 1]
    assert xs.max() - xs.min() >= 90.0  # east-west, ~100 m
    assert ys.max() - ys.min() >= 70.0  # north-south, ~80 m
    widths = {round(2 * h, 2) for _, _, h in lanes["edges"] if h > 0.5}
    assert min(widths) >= 1.8
    assert max(widths) <= 3.0


def test_every_place_is_reachable_with_inflation(campus_grid: OccupancyGrid) -> None:
    """Plan-free check: free space shrunk by robot radius + inflation is one connected piece
    holding every place (so every doorway and corridor leaves the robot >= 0.8 m from walls)."""
    free = campus_grid.data == FREE
    clearance = ndimage.distance_transform_edt(free) * campus_grid.resolution
    ok = clearance > ROBOT_RADIUS_M + INFLATION_M
    labels, _ = ndimage.label(ok)
    places = load_places(package_data("maps", "campus", "waypoints.yaml"))
    ids = set()
    for p in places:
        r, c = world_to_cell(campus_grid, p.pose.x, p.pose.y)
        assert ok[int(r), int(c)], f"{p.name} is closer than {ROBOT_RADIUS_M + INFLATION_M} m to a wall"
        ids.add(int(labels[int(r), int(c)]))
    assert len(ids) == 1, "some places are cut off from the others"


def test_docking_station_is_the_initial_pose() -> None:
    settings = load_profile(None)
    assert settings.nav.initial_place == "DOCKING_STATION"
    places = load_places(waypoints_yaml(settings))
    dock = places.get("DOCKING_STATION").pose
    assert (dock.x, dock.y) == (47.3, 57.5)


def test_clutter_is_off_the_walking_lanes_and_places() -> None:
    world = yaml.safe_load(package_data("maps", "campus", "world.yaml").read_text())
    boxes = [low_obstacle(c, "test") for c in world["low_obstacles"]]
    assert boxes
    assert all(b.height_m < 0.527 for b in boxes)  # below the lidar
    arr = np.array([[b.x, b.y, b.length_m, b.depth_m, b.yaw] for b in boxes])
    lanes = build_lanes()
    nodes = np.array(lanes["nodes"])
    for a, b, _ in lanes["edges"]:
        for f in np.linspace(0, 1, 50):
            x, y = nodes[a] + f * (nodes[b] - nodes[a])
            assert _box_distance(x, y, arr).min() > ROBOT_RADIUS_M + 0.3, (x, y)
    places = load_places(package_data("maps", "campus", "waypoints.yaml"))
    for p in places:
        assert _box_distance(p.pose.x, p.pose.y, arr).min() > 1.0, p.name
    assert math.isclose(len(boxes), 4)
