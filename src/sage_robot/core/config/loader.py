"""Load a profile: YAML → :class:`Settings`, or one clear message naming file, key and fix."""

from __future__ import annotations

import contextlib
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from pydantic import Field, ValidationError

from sage_robot.core.config.areas import (
    EmailSettings,
    KbSettings,
    LlmSettings,
    NavSettings,
    SimSettings,
    SlamSettings,
    VoiceSettings,
    WebSettings,
)
from sage_robot.core.config.base import Section
from sage_robot.core.config.bus import BusSettings
from sage_robot.core.config.devices import CameraSettings, LidarSettings
from sage_robot.core.config.ops import OpsSettings
from sage_robot.core.config.processes import ProcessSettings
from sage_robot.core.config.robot import BatterySettings, McuSettings, RobotSettings
from sage_robot.core.errors import ConfigError


class Settings(Section):
    """The whole profile. Every section has defaults for the simulated seed robot."""

    robot: RobotSettings = Field(default_factory=RobotSettings)
    mcu: McuSettings = Field(default_factory=McuSettings)
    battery: BatterySettings = Field(default_factory=BatterySettings)
    lidar: LidarSettings = Field(default_factory=LidarSettings)
    camera: CameraSettings = Field(default_factory=CameraSettings)
    ops: OpsSettings = Field(default_factory=OpsSettings)
    sim: SimSettings = Field(default_factory=SimSettings)
    nav: NavSettings = Field(default_factory=NavSettings)
    voice: VoiceSettings = Field(default_factory=VoiceSettings)
    llm: LlmSettings = Field(default_factory=LlmSettings)
    kb: KbSettings = Field(default_factory=KbSettings)
    web: WebSettings = Field(default_factory=WebSettings)
    email: EmailSettings = Field(default_factory=EmailSettings)
    slam: SlamSettings = Field(default_factory=SlamSettings)
    bus: BusSettings = Field(default_factory=BusSettings)
    processes: ProcessSettings = Field(default_factory=ProcessSettings)
    secrets_file: str = Field("", description="Key file (KEY=VALUE or JSON), mode 600.")


def default_profile_path() -> Path:
    """The profile shipped in the package (the simulated robot)."""
    return Path(str(resources.files("sage_robot") / "data" / "profiles" / "sim.yaml"))


def _line_index(text: str) -> dict[tuple[str, ...], int]:
    """Map each key path of a YAML document to its 1-based line, for error messages."""
    index: dict[tuple[str, ...], int] = {}

    def walk(node: Any, path: tuple[str, ...]) -> None:
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                sub = (*path, str(key.value))
                index[sub] = key.start_mark.line + 1
                walk(value, sub)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                sub = (*path, str(i))
                index[sub] = item.start_mark.line + 1
                walk(item, sub)

    with contextlib.suppress(yaml.YAMLError):
        walk(yaml.compose(text), ())
    return index


def _describe(err: Any) -> str:
    kind, msg, value = err["type"], err["msg"], err.get("input")
    if kind == "extra_forbidden":
        return "unknown key (check the spelling; see docs/configuration.md)"
    if kind == "missing":
        return "required key is missing"
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return f"{msg[0].lower() + msg[1:]}, got {shown}"


def parse_profile(text: str, source: str = "<profile>") -> Settings:
    """Validate YAML text into settings. Raises ConfigError with every problem listed."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(f"{source}:{where}: not valid YAML: {problem}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"{source}: expected a mapping of sections (robot:, nav:, ...), got {type(data).__name__}"
        )
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        lines = _line_index(text)
        problems = []
        for err in exc.errors():
            path = tuple(str(p) for p in err["loc"])
            key = ".".join(path) or "(top level)"
            line = next(
                (lines[path[:n]] for n in range(len(path), 0, -1) if path[:n] in lines), None
            )
            at = f" (line {line})" if line else ""
            problems.append(f"{source}: {key}{at}: {_describe(err)}")
        raise ConfigError("\n".join(problems)) from None


def load_profile(
    path: str | Path | None = None, overrides: dict[str, Any] | None = None
) -> Settings:
    """Load a profile file (default: the shipped simulated robot), then apply overrides.

    ``overrides`` is a nested dict merged over the file (the CLI's flags); the caller's
    dict is never modified.
    """
    p = Path(path) if path else default_profile_path()
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: profile not found") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the profile: {exc.strerror}") from None
    settings = parse_profile(text, str(p))
    if overrides:
        merged = _merge(settings.model_dump(), overrides)
        try:
            settings = Settings.model_validate(merged)
        except ValidationError as exc:
            first = exc.errors()[0]
            key = ".".join(str(x) for x in first["loc"])
            raise ConfigError(f"command-line override {key}: {_describe(first)}") from None
    return settings


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out
