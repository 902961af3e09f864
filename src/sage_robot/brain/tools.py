"""The tool registry: what the conversation agent (and the offline brain) can do.

A tool is a name, a description for the model, a JSON schema for its arguments and an
async function. :meth:`ToolRegistry.call` validates the arguments against the schema and
turns every expected failure into a :class:`ToolResult` with an error a model can read
and recover from (unknown place → the list of places); it never raises for bad input.
Tools register themselves with :func:`tool`; the implementations are in
:mod:`sage_robot.brain.toolbox`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from jsonschema import Draft202012Validator

if TYPE_CHECKING:
    from sage_robot.brain.robot import RobotLink
    from sage_robot.core.config import Settings

_log = logging.getLogger("sage.brain.tools")


@dataclass(frozen=True)
class ToolResult:
    """What a tool returns: data for the model, or an error it can act on."""

    ok: bool
    data: dict[str, Any] = field(default_factory=dict)
    error: str = ""

    def to_json(self) -> str:
        """What the model reads: the data, or the error with any data that goes with it
        (a refused drive says ``goal_started: false``)."""
        return json.dumps(self.data if self.ok else {"error": self.error, **self.data}, default=str)

    @classmethod
    def fail(cls, error: str, **data: Any) -> ToolResult:
        return cls(False, data, error)


@dataclass
class ToolContext:
    """What tools reach: the robot over the bus, the settings and the secrets."""

    robot: RobotLink
    settings: Settings


ToolFn = Callable[[ToolContext, dict[str, Any]], Awaitable[ToolResult]]


@dataclass(frozen=True)
class Tool:
    name: str
    description: str
    parameters: dict[str, Any]
    fn: ToolFn

    def spec(self) -> dict[str, Any]:
        """The OpenAI ``tools`` entry."""
        return {
            "type": "function",
            "function": {
                "name": self.name,
                "description": self.description,
                "parameters": self.parameters,
            },
        }


@dataclass(frozen=True)
class ToolCall:
    """One call made during a turn, for `sage ask --json` and the tests."""

    name: str
    arguments: dict[str, Any] | str
    result: ToolResult

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "arguments": self.arguments,
            "ok": self.result.ok,
            "result": self.result.data if self.result.ok else {"error": self.result.error},
        }


TOOLS: dict[str, Tool] = {}


def tool(name: str, description: str, parameters: dict[str, Any]) -> Callable[[ToolFn], ToolFn]:
    """Register ``fn`` as a tool; the schema is checked once, here."""
    Draft202012Validator.check_schema(parameters)

    def wrap(fn: ToolFn) -> ToolFn:
        if name in TOOLS:
            raise ValueError(f"tool {name!r} registered twice")
        TOOLS[name] = Tool(name, description, parameters, fn)
        return fn

    return wrap


def no_args() -> dict[str, Any]:
    return {"type": "object", "properties": {}, "additionalProperties": False}


class ToolRegistry:
    """The tools one brain offers, with argument checking and error capture."""

    def __init__(self, ctx: ToolContext, names: list[str] | None = None) -> None:
        from sage_robot.brain import toolbox  # noqa: F401  (registers the tools)

        unknown = [n for n in names or [] if n not in TOOLS]
        if unknown:
            raise ValueError(f"unknown tool(s) {', '.join(unknown)}; known: {', '.join(TOOLS)}")
        self.ctx = ctx
        self.tools = {n: TOOLS[n] for n in (names or list(TOOLS))}
        self._validators = {n: Draft202012Validator(t.parameters) for n, t in self.tools.items()}

    def specs(self) -> list[dict[str, Any]]:
        return [t.spec() for t in self.tools.values()]

    def parse_arguments(self, raw: str | dict[str, Any] | None) -> dict[str, Any] | str:
        """Arguments as a dict, or an error message when they are not a JSON object."""
        if isinstance(raw, dict):
            return raw
        if raw is None or not raw.strip():
            return {}
        try:
            value = json.loads(raw)
        except json.JSONDecodeError as exc:
            return f"the arguments are not valid JSON ({exc.msg} at character {exc.pos}): {raw[:200]}"
        if not isinstance(value, dict):
            return f"the arguments must be a JSON object, got {type(value).__name__}"
        return value

    async def call(self, name: str, raw_arguments: str | dict[str, Any] | None) -> ToolCall:
        args = self.parse_arguments(raw_arguments)
        shown: dict[str, Any] | str = args if isinstance(args, dict) else str(raw_arguments)
        tool_ = self.tools.get(name)
        if tool_ is None:
            return ToolCall(
                name,
                shown,
                ToolResult.fail(f"there is no tool named {name!r}; tools: {', '.join(self.tools)}"),
            )
        if isinstance(args, str):
            return ToolCall(name, shown, ToolResult.fail(args))
        errors = sorted(self._validators[name].iter_errors(args), key=lambda e: list(e.path))
        if errors:
            problems = "; ".join(
                (f"{'/'.join(map(str, e.path))}: " if e.path else "") + e.message for e in errors
            )
            return ToolCall(name, args, ToolResult.fail(f"invalid arguments for {name}: {problems}"))
        try:
            result = await tool_.fn(self.ctx, args)
        except Exception as exc:  # a tool bug must not end the conversation
            _log.exception("tool %s failed", name)
            result = ToolResult.fail(f"{name} failed inside the robot: {exc}")
        return ToolCall(name, args, result)
