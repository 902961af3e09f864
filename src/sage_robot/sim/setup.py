"""Build the simulated world from the robot profile and, optionally, a scenario."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sage_robot.core.config import Settings
from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import FREE, read_map, world_to_cell
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.core.msgs.sim import LowObstacle
from sage_robot.core.paths import waypoints_yaml, world_map_yaml
from sage_robot.core.places import Places, load_places
from sage_robot.sim.lidar import LidarSpec
from sage_robot.sim.people import PERSON_RADIUS_M, WALL_MARGIN_M, Lanes
from sage_robot.sim.raycast import GridRaycaster
from sage_robot.sim.scenario import Scenario, low_obstacle
from sage_robot.sim.spawn import people_from_specs, spawn_crowd
from sage_robot.sim.world import World

WORLD_FILE = "world.yaml"  # beside a map: its low obstacles and walking lanes
FREE_SPOT_CLEARANCE_M = 0.6  # random people on a map without lanes start this far from walls
SPAWN_STREAM = 2  # SeedSequence child used for placing people (the world uses 0 and 1)


def load_world_file(map_yaml: Path) -> dict[str, Any]:
    """``world.yaml`` beside the map, or an empty description."""
    path = map_yaml.with_name(WORLD_FILE)
    if not path.exists():
        return {}
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping with low_obstacles and lanes")
    return data


def _load_places(settings: Settings) -> Places:
    path = waypoints_yaml(settings)
    return load_places(path) if path.exists() else Places([], str(path))


def pose_resolver(places: Places) -> Any:
    """A function turning a place name or [x, y(, yaw)] into a pose (m, rad)."""

    def resolve(value: Any, where: str) -> tuple[float, float, float]:
        if isinstance(value, str):
            place = places.get(value) if value in places else places.resolve(value)
            if place is None:
                raise ConfigError(f"{where}: unknown place {value!r}; places: {', '.join(places.names())}")
            return place.pose.as_tuple()
        try:
            nums = [float(v) for v in value]
        except (TypeError, ValueError):
            nums = []
        if len(nums) not in (2, 3):
            raise ConfigError(f"{where}: expected a place name or [x, y, yaw], got {value!r}")
        return (nums[0], nums[1], nums[2] if len(nums) == 3 else 0.0)

    return resolve


def _walkable_from(grid: OccupancyGrid, raycaster: GridRaycaster,
                   start: tuple[float, float, float]) -> np.ndarray:
    """Known-free cells a person fits on that connect to the start (the robot's part of the
    building: not the specks and closed-off rooms of a SLAM map); every such cell when the
    start itself is not on one."""
    from scipy import ndimage

    ok = (grid.data == FREE) & (raycaster.edt_cells * raycaster.res >= PERSON_RADIUS_M + WALL_MARGIN_M)
    labels, _ = ndimage.label(ok)
    r, c = world_to_cell(grid, start[0], start[1])
    row, col = int(r), int(c)
    inside = 0 <= row < grid.height and 0 <= col < grid.width
    label = int(labels[row, col]) if inside else 0
    return np.asarray(labels == label) if label else np.asarray(ok)


def build_world(settings: Settings, scenario: Scenario | None = None) -> World:
    """The world the profile (and scenario) describe. Errors name the file and the problem."""
    map_path = world_map_yaml(settings)
    grid = read_map(map_path)
    places = _load_places(settings)
    extras = load_world_file(map_path)
    resolve = pose_resolver(places)
    start = resolve(
        scenario.start if scenario and scenario.start is not None else settings.nav.initial_place,
        "start pose",
    )
    raycaster = GridRaycaster(grid)
    if not raycaster.is_free(start[0], start[1]):
        raise ConfigError(
            f"{map_path}: the start pose ({start[0]:.2f}, {start[1]:.2f}) is not on free floor of the map"
        )
    sim = settings.sim
    low: list[LowObstacle] = []
    if sim.clutter and (scenario is None or scenario.default_clutter):
        low += [
            low_obstacle(c, f"{map_path.with_name(WORLD_FILE)}: low_obstacles[{i}]")
            for i, c in enumerate(extras.get("low_obstacles") or [])
        ]
    if scenario is not None:
        low += list(scenario.clutter)
    lanes = Lanes.from_dict(extras.get("lanes"))
    people = people_from_specs(list(scenario.people) if scenario else [], 0, resolve)
    rng = np.random.default_rng(np.random.SeedSequence(sim.seed).spawn(SPAWN_STREAM + 1)[SPAWN_STREAM])
    walkable = _walkable_from(grid, raycaster, start)
    free_cells = np.flatnonzero(
        walkable.ravel() & (raycaster.edt_cells.ravel() * raycaster.res >= FREE_SPOT_CLEARANCE_M)
    )

    def floor_clearance(x: float, y: float) -> np.ndarray:
        """The clearance of a spot on the robot's floor; 0 elsewhere (unknown space outside the
        walls is no floor: a standing group was placed out there in the TurtleBot sandbox)."""
        r, c = world_to_cell(grid, x, y)
        row, col = int(r), int(c)
        on_floor = 0 <= row < grid.height and 0 <= col < grid.width and bool(walkable[row, col])
        return raycaster.clearance(x, y) if on_floor else np.zeros(1)

    def sample_free(g: np.random.Generator) -> tuple[float, float]:
        if free_cells.size == 0:
            raise ConfigError(f"{map_path}: no free space for simulated people")
        row, col = divmod(int(free_cells[int(g.integers(free_cells.size))]), grid.width)
        o = grid.origin
        return (o.x + (col + 0.5) * grid.resolution, o.y + (row + 0.5) * grid.resolution)

    def line_of_sight(x0: float, y0: float, x1: float, y1: float) -> bool:
        d = math.hypot(x1 - x0, y1 - y0)
        hit = raycaster.cast(x0, y0, np.array([math.atan2(y1 - y0, x1 - x0)]), d + 0.1)[0]
        return bool(hit >= d)

    place_poses = [p.pose.as_tuple() for p in places if p.name != settings.nav.initial_place]
    crowd = spawn_crowd(
        sim.pedestrians,
        rng,
        start[:2],
        lanes,
        place_poses,
        floor_clearance,
        sample_free,
        line_of_sight,
        start[2],
        keep_off=[(p.pose.x, p.pose.y) for p in places],
    )
    for p in crowd:  # numbered after the scenario's people (a companion keeps its leader)
        p.id += len(people)
        p.leader += len(people) if p.leader >= 0 else 0
    people += crowd
    for i, p in enumerate(people):
        if float(raycaster.clearance(p.x, p.y)[0]) < PERSON_RADIUS_M:
            raise ConfigError(f"person {i} at ({p.x:.2f}, {p.y:.2f}) stands in a wall")
    lm = settings.robot.lidar
    spec = LidarSpec(
        beams=sim.lidar_beams,
        dropout_probability=sim.lidar_dropout,
        mount_x_m=lm.x_m,
        mount_y_m=lm.y_m,
        mount_z_m=lm.z_m,
        mount_yaw_rad=lm.yaw_rad,
    )
    try:
        return World(
            grid,
            start,
            robot_radius=settings.robot.radius_m,
            lidar=spec,
            low_obstacles=tuple(low),
            people=people,
            lanes=lanes,
            seed=sim.seed,
            raycaster=raycaster,
            track_width_m=settings.robot.track_width_m,
            people_model=sim.people_model,
            ignore_share=sim.people_ignore_share,
        )
    except ValueError as exc:
        raise ConfigError(f"{map_path}: {exc}") from None
