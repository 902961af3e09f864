"""Scenarios: repeatable simulator runs described in YAML, for tests and benchmarks.

::

    name: cafe_run
    map: ""                   # map YAML (relative to this file); empty = the default building
    start: DOCKING_STATION    # a place name or [x, y, yaw]; empty = nav.initial_place
    seed: 7                   # world seed (people, lidar noise)
    duration_s: 120           # stop after this much simulated time
    pedestrians: 0            # random people besides the listed ones; empty = sim.pedestrians
    people:                   # kind: walker | stander | group | approacher
      - {kind: stander, at: [30.0, 40.0]}
      - {kind: walker, at: GUELLY_DELLY, to: [60.0, 40.0], speed: 1.1}
      - {kind: approacher, at: [52.0, 57.5], start_s: 3, stay_s: 40}
    default_clutter: true     # the building's own benches and carts (world.yaml)
    clutter:                  # more low obstacles
      - {name: bench1, kind: bench, center: [55.0, 40.0], size: [1.6, 0.45], yaw: 0.0, height: 0.45}
    battery: 0.8              # initial charge 0..1 of the firmware model's battery
    events:                   # at (s) and exactly one action
      - {at: 1.0, cmd_vel: [0.3, 0.0]}   # a standing /cmd_vel (v m/s, w rad/s), re-sent at 20 Hz
      - {at: 5.0, goal: GUELLY_DELLY}    # a navigate_to goal (needs the navigation node)
      - {at: 8.0, heard: "take me to the cafe"}   # transcribed words: a converse goal to the brain
      - {at: 9.0, say: "hey jarvis, where is the cafe"}   # spoken into the sim microphone
      - {at: 60.0, stop: true}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs.sim import LowObstacle

SCENARIO_KEYS = {
    "name",
    "map",
    "waypoints",
    "start",
    "seed",
    "duration_s",
    "pedestrians",
    "people",
    "default_clutter",
    "clutter",
    "battery",
    "events",
    "description",
}
EVENT_ACTIONS = ("cmd_vel", "goal", "heard", "say", "stop")
CLUTTER_KEYS = {"name", "kind", "center", "size", "yaw", "height"}
DEFAULT_LOW_HEIGHT_M = 0.45


@dataclass(frozen=True)
class TimedEvent:
    at: float  # s of simulated time
    action: str  # one of EVENT_ACTIONS
    value: Any


@dataclass(frozen=True)
class Scenario:
    name: str = "scenario"
    map: str = ""
    waypoints: str = ""
    start: Any = None
    seed: int | None = None
    duration_s: float | None = None
    pedestrians: int | None = None
    people: tuple[dict[str, Any], ...] = ()
    default_clutter: bool = True
    clutter: tuple[LowObstacle, ...] = ()
    battery: float | None = None
    events: tuple[TimedEvent, ...] = field(default_factory=tuple)
    description: str = ""

    def settings_overrides(self) -> dict[str, Any]:
        """Profile overrides this scenario implies (map, seed, crowd size)."""
        sim: dict[str, Any] = {}
        nav: dict[str, Any] = {}
        if self.map:
            sim["world_map"] = self.map
            nav["map"] = self.map
        if self.waypoints:
            nav["waypoints"] = self.waypoints
        if self.seed is not None:
            sim["seed"] = self.seed
        if self.pedestrians is not None:
            sim["pedestrians"] = self.pedestrians
        return {k: v for k, v in (("sim", sim), ("nav", nav)) if v}


def low_obstacle(entry: Any, where: str) -> LowObstacle:
    if not isinstance(entry, dict):
        raise ConfigError(f"{where}: expected a mapping, got {entry!r}")
    unknown = set(entry) - CLUTTER_KEYS
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(sorted(unknown))}; allowed: "
            f"{', '.join(sorted(CLUTTER_KEYS))}"
        )
    try:
        cx, cy = (float(v) for v in entry["center"])
        length, depth = (float(v) for v in entry.get("size", (1.6, 0.45)))
        return LowObstacle(
            str(entry.get("name", where)),
            cx,
            cy,
            length,
            depth,
            float(entry.get("yaw", 0.0)),
            float(entry.get("height", DEFAULT_LOW_HEIGHT_M)),
            str(entry.get("kind", "bench")),
        )
    except KeyError:
        raise ConfigError(f"{where}: needs 'center: [x, y]'") from None
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: center and size are [x, y] and [length, depth] in metres") from None


def _event(entry: Any, where: str) -> TimedEvent:
    if not isinstance(entry, dict) or "at" not in entry:
        raise ConfigError(f"{where}: expected {{at: SECONDS, <action>: ...}}, got {entry!r}")
    actions = [k for k in entry if k != "at"]
    if len(actions) != 1 or actions[0] not in EVENT_ACTIONS:
        raise ConfigError(f"{where}: needs exactly one of {', '.join(EVENT_ACTIONS)}, got {actions}")
    try:
        at = float(entry["at"])
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: at must be a number of seconds, got {entry['at']!r}") from None
    action, value = actions[0], entry[actions[0]]
    if action == "cmd_vel":
        try:
            v, w = (float(x) for x in value)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: cmd_vel must be [v m/s, w rad/s], got {value!r}") from None
        value = (v, w)
    elif action in ("goal", "heard", "say") and not isinstance(value, str):
        raise ConfigError(f"{where}: {action} must be text, got {value!r}")
    return TimedEvent(at, action, value)


def parse_scenario(data: Any, source: str, base: Path | None = None) -> Scenario:
    _check_keys(data, source)
    people, clutter, events = _lists(data, source)
    battery, pedestrians, duration = _checked_numbers(data, source)
    return Scenario(
        name=str(data.get("name") or Path(source).stem),
        map=_path(data, "map", base),
        waypoints=_path(data, "waypoints", base),
        start=data.get("start"),
        seed=_number(data, "seed", int, source),
        duration_s=duration,
        pedestrians=pedestrians,
        people=tuple(people),
        default_clutter=bool(data.get("default_clutter", True)),
        clutter=tuple(low_obstacle(c, f"{source}: clutter[{i}]") for i, c in enumerate(clutter)),
        battery=battery,
        events=tuple(
            sorted((_event(e, f"{source}: events[{i}]") for i, e in enumerate(events)), key=lambda e: e.at)
        ),
        description=str(data.get("description", "")),
    )


def _check_keys(data: Any, source: str) -> None:
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a scenario is a YAML mapping")
    unknown = set(data) - SCENARIO_KEYS
    if unknown:
        raise ConfigError(
            f"{source}: unknown key(s) {', '.join(sorted(unknown))}; allowed: "
            f"{', '.join(sorted(SCENARIO_KEYS))}"
        )


def _lists(data: dict[str, Any], source: str) -> tuple[list[Any], list[Any], list[Any]]:
    """(people, clutter, events): each a list, empty when left out."""
    people = data.get("people") or []
    if not isinstance(people, list):
        raise ConfigError(f"{source}: people must be a list")
    clutter = data.get("clutter") or []
    events = data.get("events") or []
    if not isinstance(clutter, list) or not isinstance(events, list):
        raise ConfigError(f"{source}: clutter and events must be lists")
    return people, clutter, events


def _checked_numbers(data: dict[str, Any], source: str) -> tuple[float | None, int | None, float | None]:
    """(battery, pedestrians, duration_s), each None when left out, checked for range."""
    battery = _number(data, "battery", float, source)
    if battery is not None and not 0.0 <= battery <= 1.0:
        raise ConfigError(f"{source}: battery is a charge fraction 0..1, got {battery}")
    pedestrians = _number(data, "pedestrians", int, source)
    if pedestrians is not None and pedestrians < 0:
        raise ConfigError(f"{source}: pedestrians must be >= 0")
    duration = _number(data, "duration_s", float, source)
    if duration is not None and duration <= 0:
        raise ConfigError(f"{source}: duration_s must be > 0")
    return battery, pedestrians, duration


def _path(data: dict[str, Any], key: str, base: Path | None) -> str:
    """A file name, made absolute from ``base`` (the scenario's folder) when relative."""
    value = str(data.get(key) or "")
    if value and base is not None and not Path(value).is_absolute():
        value = str((base / value).resolve())
    return value


def _number(data: dict[str, Any], key: str, kind: type, source: str) -> Any:
    value = data.get(key)
    if value is None:
        return None
    try:
        return kind(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: {key} must be a {kind.__name__}, got {value!r}") from None


BUNDLED_DIR = Path(__file__).with_name("scenarios")  # example scenarios shipped with the package


def bundled_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``sim/scenarios/`` (``sage sim --scenario NAME``)."""
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.yaml"))


def load_scenario(path: str | Path) -> Scenario:
    """A scenario file, or the name of a bundled one (``low_bench``, ``visitor``...)."""
    p = Path(path)
    if not p.exists() and p.suffix == "" and (BUNDLED_DIR / f"{p.name}.yaml").exists():
        p = BUNDLED_DIR / f"{p.name}.yaml"
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(
            f"{p}: scenario file not found (bundled scenarios: {', '.join(bundled_scenarios())})"
        ) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML: {exc}") from None
    return parse_scenario(data, str(p), p.parent)
