"""Where the files a run needs are: the profile's paths, or what the package ships."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from sage_robot.core.config import Settings

DEFAULT_BUILDING = "campus"  # src/sage_robot/data/maps/campus/: the generated first floor


def package_data(*parts: str) -> Path:
    return Path(str(resources.files("sage_robot").joinpath("data", *parts)))


def map_yaml(settings: Settings) -> Path:
    """The navigation map: ``nav.map``, or the shipped default building."""
    return Path(settings.nav.map) if settings.nav.map else package_data("maps", DEFAULT_BUILDING, "map.yaml")


def waypoints_yaml(settings: Settings) -> Path:
    """The places file: ``nav.waypoints``, or the default building's."""
    if settings.nav.waypoints:
        return Path(settings.nav.waypoints)
    if settings.nav.map:
        return Path(settings.nav.map).with_name("waypoints.yaml")
    return package_data("maps", DEFAULT_BUILDING, "waypoints.yaml")


def world_map_yaml(settings: Settings) -> Path:
    """The simulator's true building: ``sim.world_map``, or the navigation map."""
    return Path(settings.sim.world_map) if settings.sim.world_map else map_yaml(settings)


def state_dir() -> Path:
    """Writable per-user state (knowledge base, generated password, recordings)."""
    base = os.environ.get("SAGE_STATE_DIR") or os.path.join(
        os.environ.get("XDG_STATE_HOME", os.path.expanduser("~/.local/state")), "sage"
    )
    path = Path(base)
    path.mkdir(parents=True, exist_ok=True)
    return path
