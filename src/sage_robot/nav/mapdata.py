"""Everything navigation loads for one map: the grid, its Nav2 filter masks and its places."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from sage_robot.core.config import Settings
from sage_robot.core.errors import ConfigError
from sage_robot.core.log import StructLogger
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Event, OccupancyGrid
from sage_robot.core.paths import map_yaml, waypoints_yaml
from sage_robot.core.places import Places, load_places
from sage_robot.nav.costmap import Costmap


@dataclass(frozen=True)
class MapData:
    path: Path
    grid: OccupancyGrid
    places: Places
    keepout: OccupancyGrid | None = None
    speed: OccupancyGrid | None = None

    def costmap(self, inscribed_m: float, inflation_m: float, cost_scaling: float) -> Costmap:
        return Costmap.from_grid(self.grid, inscribed_m, inflation_m, cost_scaling, self.keepout, self.speed)


def _mask(explicit: str, map_path: Path, suffix: str) -> OccupancyGrid | None:
    if explicit:
        return read_map(explicit)
    beside = map_path.with_name(f"{map_path.stem}_{suffix}.yaml")
    return read_map(beside) if beside.exists() else None


def load_map_data(map_path: str | Path, waypoints: str | Path | None = None, keepout: str = "",
                  speed: str = "") -> MapData:
    """Read a map, its masks (explicit paths, else ``NAME_keepout.yaml`` / ``NAME_speed.yaml``
    beside the map) and its waypoints (else ``waypoints.yaml`` beside the map; none = no places)."""
    path = Path(map_path)
    grid = read_map(path)
    if abs(grid.origin.theta) > 1e-6:
        raise ConfigError(f"{path}: navigation needs a map whose origin yaw is 0")
    wp = Path(waypoints) if waypoints else path.with_name("waypoints.yaml")
    places = load_places(wp) if (waypoints or wp.exists()) else Places([], str(wp))
    return MapData(path, grid, places, _mask(keepout, path, "keepout"), _mask(speed, path, "speed"))


PLACES_CHANGED = "places_changed"  # Event kind: the waypoints file was rewritten (web admin)


def reload_places(data: MapData) -> MapData:
    """``data`` with its places read again from their file (raises ConfigError when the file
    is missing or broken; the caller keeps the old places then)."""
    return replace(data, places=load_places(data.places.source))


def is_places_changed(event: Event) -> bool:
    return event.kind == PLACES_CHANGED


def places_after(event: Event, data: MapData, log: StructLogger) -> MapData:
    """``data`` with its places re-read when ``event`` says the waypoints file changed; on a
    broken file, the old places (with a warning)."""
    if not is_places_changed(event):
        return data
    try:
        data = reload_places(data)
    except ConfigError as exc:
        log.warning("places not reloaded: keeping the old ones", error=str(exc))
        return data
    log.info("places reloaded", places=len(data.places))
    return data


def load_for(settings: Settings) -> MapData:
    """The map of a profile (``nav.map`` or the shipped building)."""
    nav = settings.nav
    wp = waypoints_yaml(settings)
    return load_map_data(map_yaml(settings), wp if (nav.waypoints or wp.exists()) else None,
                         nav.keepout_mask, nav.speed_mask)
