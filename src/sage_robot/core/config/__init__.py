"""The robot profile: one YAML file validated into typed, frozen settings."""

from sage_robot.core.config.loader import (
    Settings,
    default_profile_path,
    load_profile,
    parse_profile,
)
from sage_robot.core.config.secrets import read_secret

__all__ = ["Settings", "default_profile_path", "load_profile", "parse_profile", "read_secret"]
