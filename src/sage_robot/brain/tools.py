"""The tool registry: what the conversation agent (and the offline brain) can do.

A tool is a name, a description for the model, one pydantic model of its arguments
(a :class:`ToolArgs`) and an async function that takes them, validated. The JSON schema
the LLM is given is generated from that model (:func:`openai_parameters`), and the
arguments the LLM sends are validated by the same model, so the two cannot drift apart.
:meth:`ToolRegistry.call` turns every expected failure into a :class:`ToolResult` with an
error a model can read and recover from (bad arguments → what is wrong with each; unknown
place → the list of places); it never raises for bad input. Tools register themselves
with :func:`tool`; the implementations are in :mod:`sage_robot.brain.toolbox`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

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


class ToolArgs(BaseModel):
    """The arguments of one tool: subclass it with one field per argument (type, limits,
    default, ``description`` for the model). Arguments it does not name are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class NoArgs(ToolArgs):
    """The arguments of a tool that takes none."""


A = TypeVar("A", bound=ToolArgs)
ToolFn = Callable[[ToolContext, A], Awaitable[ToolResult]]
_SCHEMA_DROPPED = frozenset({"title"})  # pydantic's names for the model and its fields


def openai_parameters(args: type[ToolArgs]) -> dict[str, Any]:
    """The JSON schema of ``args`` in the shape of OpenAI function calling: an object with
    ``properties``, ``required`` (when any) and ``additionalProperties: false``; without
    pydantic's titles, the model's docstring or ``$defs`` (references are inlined), and an
    optional argument (``X | None = None``) shown as ``X``, not required (as the model was
    always told; an explicit ``null`` from it is still accepted, as leaving it out)."""
    schema = args.model_json_schema()
    defs = schema.pop("$defs", {})
    schema.pop("description", None)  # the docstring is for the code; the tool has its own

    def clean(node: Any, seen: tuple[str, ...] = ()) -> Any:
        if isinstance(node, list):
            return [clean(n, seen) for n in node]
        if not isinstance(node, dict):
            return node
        if "$ref" in node:
            name = node["$ref"].rsplit("/", 1)[-1]
            if name in seen:
                raise TypeError(f"{args.__name__}: recursive argument types are not for tools")
            return clean({**defs[name], **{k: v for k, v in node.items() if k != "$ref"}}, (*seen, name))
        out = {k: ({p: clean(v, seen) for p, v in node[k].items()} if k == "properties" else clean(v, seen))
               for k, v in node.items() if k not in _SCHEMA_DROPPED}  # fmt: skip
        branches = out.get("anyOf")
        if isinstance(branches, list) and {"type": "null"} in branches and len(branches) == 2:
            out.pop("anyOf")
            if out.get("default", ...) is None:
                out.pop("default")
            out = {**next(b for b in branches if b != {"type": "null"}), **out}
        return out

    params: dict[str, Any] = clean(schema)
    params.setdefault("properties", {})
    if params.get("type") != "object" or params.get("additionalProperties") is not False:
        raise TypeError(f"{args.__name__}: tool arguments must be a ToolArgs model (an object, no extras)")
    return params


def describe_errors(exc: ValidationError, parameters: dict[str, Any]) -> str:
    """Pydantic's errors as a line a model can act on: ``where: what is wrong (got what)``."""
    problems = []
    for err in exc.errors():
        where = "/".join(str(p) for p in err["loc"]) or "arguments"
        if err["type"] == "extra_forbidden":
            known = ", ".join(parameters.get("properties", {})) or "none"
            problems.append(f"{where}: unexpected argument (the arguments are: {known})")
        elif err["type"] == "missing":
            problems.append(f"{where}: required, missing")
        else:
            got = repr(err.get("input"))
            got = got if len(got) <= 60 else got[:57] + "..."
            problems.append(f"{where}: {err['msg']} (got {got})")
    return "; ".join(problems)


@dataclass(frozen=True)
class Tool(Generic[A]):
    name: str
    description: str
    args: type[A]  # the arguments: the schema the model is given and their validation
    fn: ToolFn[A]
    parameters: dict[str, Any] = field(init=False, repr=False)  # generated from ``args``

    def __post_init__(self) -> None:
        object.__setattr__(self, "parameters", openai_parameters(self.args))

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

    def validate(self, arguments: dict[str, Any]) -> A | str:
        """The arguments as the tool takes them, or what is wrong with them (for the model)."""
        try:
            return self.args.model_validate(arguments)
        except ValidationError as exc:
            return f"invalid arguments for {self.name}: {describe_errors(exc, self.parameters)}"


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


TOOLS: dict[str, Tool[Any]] = {}


def tool(name: str, description: str, args: type[A]) -> Callable[[ToolFn[A]], ToolFn[A]]:
    """Register ``fn`` as a tool taking ``args`` (:class:`NoArgs` for none); the schema
    is generated once, here."""

    def wrap(fn: ToolFn[A]) -> ToolFn[A]:
        if name in TOOLS:
            raise ValueError(f"tool {name!r} registered twice")
        TOOLS[name] = Tool(name, description, args, fn)
        return fn

    return wrap


class ToolRegistry:
    """The tools one brain offers, with argument checking and error capture."""

    def __init__(self, ctx: ToolContext, names: list[str] | None = None) -> None:
        from sage_robot.brain import toolbox  # noqa: F401  (registers the tools)

        unknown = [n for n in names or [] if n not in TOOLS]
        if unknown:
            raise ValueError(f"unknown tool(s) {', '.join(unknown)}; known: {', '.join(TOOLS)}")
        self.ctx = ctx
        self.tools = {n: TOOLS[n] for n in (names or list(TOOLS))}

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
        valid = tool_.validate(args)
        if isinstance(valid, str):
            return ToolCall(name, args, ToolResult.fail(valid))
        try:
            result = await tool_.fn(self.ctx, valid)
        except Exception as exc:  # a tool bug must not end the conversation
            _log.exception("tool %s failed", name)
            result = ToolResult.fail(f"{name} failed inside the robot: {exc}")
        return ToolCall(name, args, result)
