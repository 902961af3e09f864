"""Named places: one waypoints file per map, the single source for navigation and the LLM.

Two formats load:

- the package's own::

    places:
      - name: GUELLY_DELLY
        pose: [12.0, 3.5, 1.57]          # x m, y m, yaw rad, map frame
        description: Engineering student café (breakfast and lunch)
        aliases: [the cafe, guelly delly, the deli]
        dwell_text: Here is the Guelly Delly ...   # optional
        title: Guelly Delly café                   # optional: the name pages show

- the seed robot's Nav2 style (``maps/new_waypoints.yaml``)::

    BIO_ENG_LAB:
      pose: {position: {x: 1, y: 2, z: 0}, orientation: {x: 0, y: 0, z: 0, w: 1}}

  optionally under a top-level ``waypoints:`` key.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sage_robot.core.errors import ConfigError
from sage_robot.core.geometry import quaternion_to_yaw
from sage_robot.core.mapio import FREE, in_bounds, world_to_cell
from sage_robot.core.msgs import OccupancyGrid, Pose2D

PLACE_KEYS = {"name", "pose", "description", "aliases", "dwell_text", "title"}
FUZZY_CUTOFF = 70.0  # rapidfuzz score (0..100) below which a spoken name matches nothing
_NUMBER_WORDS = {"three d": "3d", "3 d": "3d", "one": "1", "two": "2", "three": "3"}


def normalize(text: str) -> str:
    """Lower-case words only: 'the 3D_PRINTING_LAB!' → '3d printing lab'."""
    t = text.lower().replace("_", " ").replace("-", " ")
    t = re.sub(r"[^a-z0-9 ]+", " ", t)
    for k, v in _NUMBER_WORDS.items():
        t = re.sub(rf"\b{k}\b", v, t)
    t = re.sub(r"\b(the|a|an|to|please)\b", " ", t)
    return " ".join(t.split())


@dataclass(frozen=True)
class Place:
    name: str
    pose: Pose2D
    description: str = ""
    aliases: tuple[str, ...] = ()
    dwell_text: str = ""
    title: str = ""  # the human name pages show ("Guelly Delly café"); "" = made from the name

    def spoken_names(self) -> tuple[str, ...]:
        return (normalize(self.name), *(normalize(a) for a in self.aliases))


class Places:
    """An ordered, name-unique set of places with fuzzy look-up."""

    def __init__(self, places: list[Place] | tuple[Place, ...], source: str = "") -> None:
        self.source = source
        self._by_name: dict[str, Place] = {}
        for p in places:
            if p.name in self._by_name:
                raise ConfigError(f"{source}: place {p.name} is defined twice")
            self._by_name[p.name] = p

    def __iter__(self) -> Iterator[Place]:
        return iter(self._by_name.values())

    def __len__(self) -> int:
        return len(self._by_name)

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def names(self) -> list[str]:
        return list(self._by_name)

    def get(self, name: str) -> Place:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"unknown place {name!r}; places: {', '.join(self._by_name)}") from None

    def resolve(self, text: str, cutoff: float = FUZZY_CUTOFF) -> Place | None:
        """The place a person (or speech-to-text) meant: exact name or alias first, then fuzzy."""
        from rapidfuzz import fuzz, process

        wanted = normalize(text)
        if not wanted:
            return None
        choices: dict[str, Place] = {}
        for p in self:
            for spoken in p.spoken_names():
                if spoken == wanted:
                    return p
                choices[spoken] = p
        best = process.extractOne(wanted, list(choices), scorer=fuzz.WRatio, score_cutoff=cutoff)
        return choices[best[0]] if best else None

    def nearest(self, x: float, y: float) -> tuple[Place, float]:
        if not self._by_name:
            raise ValueError("no places")
        best = min(self, key=lambda p: (p.pose.x - x) ** 2 + (p.pose.y - y) ** 2)
        return best, float(np.hypot(best.pose.x - x, best.pose.y - y))


def _pose(value: Any, where: str) -> Pose2D:
    if isinstance(value, (list, tuple)) and len(value) == 3:
        try:
            return Pose2D(*(float(v) for v in value))
        except (TypeError, ValueError):
            pass
    if isinstance(value, dict) and "position" in value:  # Nav2 style
        try:
            pos, ori = value["position"], value.get("orientation", {"w": 1.0})
            q = (
                float(ori.get("x", 0)),
                float(ori.get("y", 0)),
                float(ori.get("z", 0)),
                float(ori.get("w", 1)),
            )
            return Pose2D(float(pos["x"]), float(pos["y"]), quaternion_to_yaw(q))
        except (TypeError, ValueError, KeyError, AttributeError):
            pass
    if isinstance(value, dict) and {"x", "y"} <= set(value):
        try:
            return Pose2D(
                float(value["x"]), float(value["y"]), float(value.get("theta", value.get("yaw", 0.0)) or 0.0)
            )
        except (TypeError, ValueError):
            pass
    raise ConfigError(
        f"{where}: pose: expected [x, y, yaw] or {{position: ..., orientation: ...}}, got {value!r}"
    )


def _place(entry: Any, where: str) -> Place:
    if not isinstance(entry, dict):
        raise ConfigError(f"{where}: expected a mapping, got {entry!r}")
    name = entry.get("name")
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"{where}: every place needs a name")
    unknown = set(entry) - PLACE_KEYS
    if unknown:
        raise ConfigError(
            f"{where} ({name}): unknown key(s) {', '.join(sorted(unknown))}; "
            f"allowed: {', '.join(sorted(PLACE_KEYS))}"
        )
    aliases = entry.get("aliases", []) or []
    if not isinstance(aliases, list) or not all(isinstance(a, str) for a in aliases):
        raise ConfigError(f"{where} ({name}): aliases must be a list of strings")
    return Place(
        name.strip(),
        _pose(entry.get("pose"), f"{where} ({name})"),
        str(entry.get("description", "")),
        tuple(aliases),
        str(entry.get("dwell_text", "")),
        str(entry.get("title", "") or "").strip(),
    )


def parse_places(data: Any, source: str) -> Places:
    if isinstance(data, dict) and isinstance(data.get("places"), list):
        return Places([_place(e, f"{source}: places[{i}]") for i, e in enumerate(data["places"])], source)
    if isinstance(data, dict) and isinstance(data.get("waypoints"), dict):
        data = data["waypoints"]
    if isinstance(data, dict) and data and all(isinstance(v, dict) for v in data.values()):
        # Nav2 / seed style: NAME: {pose: {...}} (description and aliases may be added)
        return Places(
            [_place({"name": str(k), **v}, f"{source}: {k}") for k, v in data.items()],
            source,
        )
    raise ConfigError(f"{source}: expected 'places: [...]' or NAME: {{pose: ...}} entries")


def load_places(path: str | Path) -> Places:
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: waypoints file not found") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML: {exc}") from None
    return parse_places(data, str(p))


def dump_places(places: Places) -> dict[str, Any]:
    return {
        "places": [
            {
                "name": p.name,
                "pose": [round(p.pose.x, 3), round(p.pose.y, 3), round(p.pose.theta, 4)],
                "description": p.description,
                "aliases": list(p.aliases),
                **({"dwell_text": p.dwell_text} if p.dwell_text else {}),
                **({"title": p.title} if p.title else {}),
            }
            for p in places
        ]
    }


def write_places(places: Places, path: str | Path) -> None:
    Path(path).write_text(
        yaml.safe_dump(dump_places(places), sort_keys=False, allow_unicode=True), encoding="utf-8"
    )


def validate_places(places: Places, grid: OccupancyGrid) -> None:
    """Every place must stand on a free cell inside the map; the error names the place."""
    problems = []
    for p in places:
        r, c = world_to_cell(grid, p.pose.x, p.pose.y)
        if not bool(in_bounds(grid, r, c)):
            problems.append(f"{p.name} at ({p.pose.x:.2f}, {p.pose.y:.2f}) is outside the map")
        elif int(grid.data[int(r), int(c)]) != FREE:
            what = "inside a wall" if grid.data[int(r), int(c)] > 0 else "on unknown space"
            problems.append(f"{p.name} at ({p.pose.x:.2f}, {p.pose.y:.2f}) is {what}")
    if problems:
        raise ConfigError(f"{places.source}: " + "; ".join(problems))
