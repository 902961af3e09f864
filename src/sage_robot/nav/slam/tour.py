"""Make a saved SLAM map the tour map: a profile that tours it, and its own places file.

For a map ``NAME`` saved in ``DIR`` (``DIR/NAME.yaml`` + ``NAME.trajectory.txt``),
:func:`make_tour_profile` writes:

- ``DIR/NAME.waypoints.yaml`` (kept when it exists): the places of this map, the admin page
  adds to it. A new file holds one place, ``MAPPING_START``: where mapping began (the first
  pose of the trajectory), which is where the robot stands when the tour starts.
- ``DIR/NAME.profile.yaml``: the running profile with ``nav.map``, ``nav.waypoints`` and
  ``nav.initial_place`` pointing at the map (the old map's keepout/speed masks dropped), and
  (for the simulator) ``sim.world_map`` pinned to the building the map was made in.
  ``sage sim --profile DIR/NAME.profile.yaml`` (or ``sage up --profile …``) then tours it.

The running system keeps its map: a tour map is loaded when the robot starts (the map
server, localization and navigator read it once).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sage_robot.core.config import Settings, parse_profile
from sage_robot.core.errors import ConfigError
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Pose2D
from sage_robot.core.paths import world_map_yaml
from sage_robot.core.places import Place, Places, load_places, validate_places, write_places
from sage_robot.nav.slam.store import check_name

START_PLACE = "MAPPING_START"  # the place a new map's places file starts with
START_ALIASES = ("the start", "where mapping began")
YAW_TOLERANCE_RAD = 1e-6  # navigation needs a map whose origin is not turned
PROFILE_HEADER = (
    "# Tour profile for the SLAM map {name} (written by SAGE; edit freely).\n"
    "# Tour it: sage sim --profile {path}   (real robot: sage up --profile {path})\n"
)


@dataclass(frozen=True)
class TourMap:
    name: str
    map: Path  # NAME.yaml
    waypoints: Path  # NAME.waypoints.yaml
    profile: Path  # NAME.profile.yaml
    places: int  # places in the waypoints file

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "map": str(self.map),
            "waypoints": str(self.waypoints),
            "profile": str(self.profile),
            "places": self.places,
            "command": f"sage sim --profile {self.profile}",
        }


def saved_maps(directory: str | Path) -> list[dict[str, Any]]:
    """The maps saved in ``directory`` (a ``NAME.yaml`` with its ``NAME.graph.npz``), newest first."""
    out = Path(directory)
    if not out.is_dir():
        return []
    found = [p for p in out.glob("*.yaml") if p.with_suffix(".graph.npz").exists()]
    found.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    return [
        {"name": p.stem, "yaml": str(p), "tour_profile": p.with_suffix(".profile.yaml").exists()}
        for p in found
    ]


def start_pose(map_yaml: Path) -> Pose2D:
    """The first pose of the map's trajectory (``NAME.trajectory.txt``): where mapping began."""
    traj = map_yaml.with_suffix(".trajectory.txt")
    try:
        rows = np.loadtxt(traj, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{traj}: cannot read the trajectory ({exc})") from None
    if rows.shape[0] == 0 or rows.shape[1] != 4:
        raise ConfigError(f"{traj}: expected lines 'stamp x y theta'")
    _, x, y, theta = (float(v) for v in rows[0])
    return Pose2D(x, y, theta)


def make_tour_profile(settings: Settings, directory: str | Path, name: str) -> TourMap:
    """Write ``NAME.profile.yaml`` (and ``NAME.waypoints.yaml`` if missing); see the module."""
    check_name(name)
    out = Path(directory).resolve()
    map_path = out / f"{name}.yaml"
    if not map_path.exists():
        raise ConfigError(f"no saved map {name!r} in {out}")
    grid = read_map(map_path)
    if abs(grid.origin.theta) > YAW_TOLERANCE_RAD:
        raise ConfigError(f"{map_path}: navigation needs a map whose origin yaw is 0")
    waypoints = out / f"{name}.waypoints.yaml"
    if waypoints.exists():
        places = load_places(waypoints)
    else:
        start = Place(START_PLACE, start_pose(map_path), "where mapping began", START_ALIASES)
        places = Places([start], str(waypoints))
        validate_places(places, grid)
        write_places(places, waypoints)
    if len(places) == 0:
        raise ConfigError(f"{waypoints}: no places; the robot needs one to start from")
    initial = START_PLACE if START_PLACE in places else places.names()[0]
    profile = settings.model_dump(mode="json")
    # Masks belong to the old map: NAME_keepout.yaml / NAME_speed.yaml beside the new one, if any.
    profile["nav"].update(map=str(map_path), waypoints=str(waypoints), initial_place=initial,
                          keepout_mask="", speed_mask="")  # fmt: skip
    profile["slam"]["out_dir"] = str(out)  # the admin page lists the maps saved beside this one
    # The simulator keeps the building the map was made in (else it would drive in the map).
    profile["sim"]["world_map"] = str(world_map_yaml(settings).resolve())
    path = out / f"{name}.profile.yaml"
    text = yaml.safe_dump(profile, sort_keys=False, allow_unicode=True)
    parse_profile(text, str(path))  # it must load as it is written
    try:
        path.write_text(PROFILE_HEADER.format(name=name, path=path) + text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc.strerror}") from None
    return TourMap(name, map_path, waypoints, path, len(places))
