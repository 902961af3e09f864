"""The package's layering, read from the source with ``ast`` (nothing is imported).

Every ``import`` of a ``sage_robot`` module counts, wherever it is: at the top of a module,
inside a function (lazy imports) and under ``if TYPE_CHECKING:`` (a type-only import still
ties the two modules together). ``from a.b import c`` is an edge to ``a.b.c`` when that is a
module, else to ``a.b``. Imports by name at run time (``importlib``) are not seen.

Checked:

- the layers of ``shared/ARCHITECTURE.md`` ("imports point down only"), as the table
  :data:`LAYER`: a module imports only from its own layer or lower ones;
- the two rules the same page states in words: ``brain`` and ``web`` reach navigation and
  the knowledge base through the bus, not imports; above ``sim``/``hardware`` nothing can
  tell them apart, so nothing there imports ``sim``;
- no import cycles in ``sage_robot.nav``, and no cycles elsewhere beyond the known ones.

A violation that exists today goes into an allowlist below, one named entry with a comment
saying why it is there and what would remove it; an entry that no longer matches the code
fails the test, so the list only shrinks.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

PACKAGE = "sage_robot"
SRC = Path(__file__).resolve().parents[2] / "src" / PACKAGE

# The layer diagram of ARCHITECTURE.md, bottom (0) to top. Packages on one row may import
# each other (cli uses app; the simulated firmware speaks hardware's serial protocol).
LAYER: dict[str, int] = {
    "core": 0,  # bus, clock, messages, geometry, config, logging: imports nothing of the project
    "sim": 1,  # simulated world and devices
    "hardware": 1,  # real drivers: MCU link, lidar, camera, audio
    "nav": 2,  # maps, costmaps, localization, planning, control, navigator, SLAM
    "kb": 2,  # knowledge base
    "brain": 3,  # conversation agent + tools
    "voice": 3,  # wake word, VAD, STT, TTS, DOA
    "web": 4,  # one FastAPI server
    "app": 5,  # launch profiles, supervisor, doctor, watchdog
    "cli": 5,  # the `sage` command
    "bench": 5,  # `sage bench ...`: not on the diagram; it starts whole stacks, as cli does
}
ROOT_LAYER = "core"  # sage_robot/__init__.py holds only the version: the bottom layer

# ARCHITECTURE.md: "brain reaches navigation and the knowledge base through bus services and
# actions, not imports; web likewise."
BUS_ONLY: dict[str, frozenset[str]] = {
    "brain": frozenset({"nav", "kb"}),
    "web": frozenset({"nav", "kb"}),
}
# ARCHITECTURE.md: "hardware and sim implement the same device interfaces; everything above
# cannot tell them apart." Only the launch layer (app, cli, bench) picks the simulator.
NO_SIM: frozenset[str] = frozenset({"nav", "kb", "brain", "voice", "web"})

Edge = tuple[str, str]  # (importing module, imported module)

# Known violations of the layer rules, by name. Each one is debt: remove the entry with
# the import.
ALLOWED: dict[str, Edge] = {
    # The operator page mounts the KB's REST router in-process (a lazy import). A KB served
    # over the bus (or the router mounted by the launcher) removes it.
    "web-mounts-kb-router": ("sage_robot.web.admin", "sage_robot.kb.api"),
    # ... and looks the KB node's service up under the node's typed resource key.
    "web-kb-service-key": ("sage_robot.web.admin", "sage_robot.kb.node"),
    # The SLAM page takes the save request type, the progress/save topic names and the map
    # name check from the SLAM package; they belong in core (core.msgs / core.topics).
    "web-slam-save-request": ("sage_robot.web.slam_api", "sage_robot.nav.slam.messages"),
    "web-slam-topics": ("sage_robot.web.slam_api", "sage_robot.nav.slam.node"),
    "web-slam-map-name": ("sage_robot.web.slam_api", "sage_robot.nav.slam.store"),
    # ... and lists saved maps / writes a saved map's tour profile (file work, no bus: the admin
    # chooses a tour map while no slam node runs); it belongs beside core.paths/core.places.
    "web-slam-tour-map": ("sage_robot.web.slam_api", "sage_robot.nav.slam.tour"),
    # The voice node builds the simulated microphone and speaker itself when the profile
    # says sim (a lazy import); the launcher should hand it its audio devices instead.
    "voice-builds-sim-audio": ("sage_robot.voice.node", "sage_robot.sim.audio"),
}

# Import cycles outside sage_robot.nav that exist today (each a strongly connected set of
# modules). Each one is debt: remove the entry when the cycle is broken.
KNOWN_CYCLES: dict[str, frozenset[str]] = {
    # Bus.actions builds an ActionRegistry (lazy import); actions type-checks against Bus.
    "core-bus-actions": frozenset({"sage_robot.core.bus", "sage_robot.core.actions"}),
    # The tool registry imports the tool implementations to register them, and they import
    # the registry's decorator and types.
    "brain-tools-registry": frozenset({"sage_robot.brain.tools", "sage_robot.brain.toolbox"}),
    # The MCU, safety and web benchmarks borrow each other's helpers (lazy imports).
    "bench-shared-helpers": frozenset({
        "sage_robot.bench.mcu", "sage_robot.bench.mcu_dialects", "sage_robot.bench.safety",
        "sage_robot.bench.safety_rig", "sage_robot.bench.web",
    }),
}


# ---------------------------------------------------------------- the graph
def _ours(name: str) -> bool:
    return name == PACKAGE or name.startswith(PACKAGE + ".")


def _nearest(name: str, modules: dict[str, bool]) -> str:
    """``name`` if it is a module, else its nearest enclosing package."""
    while name not in modules and "." in name:
        name = name.rpartition(".")[0]
    return name


def imports_of(source: str, module: str, is_package: bool, modules: dict[str, bool]) -> dict[str, int]:
    """The project modules ``source`` (the text of ``module``) imports → first line of each."""
    package = module if is_package else module.rpartition(".")[0]
    found: dict[str, int] = {}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            targets = [_nearest(a.name, modules) for a in node.names if _ours(a.name)]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the package, one level up per extra dot
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                source_module = ".".join(base + ([node.module] if node.module else []))
            else:
                source_module = node.module or ""
            targets = [_nearest(f"{source_module}.{a.name}", modules)
                       for a in node.names] if _ours(source_module) else []
        else:
            continue
        for target in targets:
            if target != module:
                found.setdefault(target, node.lineno)
    return found


@cache
def modules() -> dict[str, bool]:
    """Every module of the package → whether it is a package (``__init__.py``)."""
    out: dict[str, bool] = {}
    for path in sorted(SRC.rglob("*.py")):
        parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_package else parts)] = is_package
    return out


def _path(module: str) -> Path:
    rel = Path(*module.split(".")[1:])
    return SRC / rel / "__init__.py" if modules()[module] else SRC / rel.with_suffix(".py")


@cache
def graph() -> dict[str, dict[str, int]]:
    """module → {imported module: line}."""
    mods = modules()
    return {m: imports_of(_path(m).read_text(encoding="utf-8"), m, is_pkg, mods)
            for m, is_pkg in mods.items()}


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ROOT_LAYER


def cycles(g: dict[str, dict[str, int]], within: str = PACKAGE) -> list[frozenset[str]]:
    """Strongly connected sets of more than one module (Tarjan), among modules under ``within``."""
    nodes = [m for m in g if m == within or m.startswith(within + ".")]
    inside = set(nodes)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[frozenset[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in g[v]:
            if w not in inside:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(frozenset(component))

    for v in nodes:
        if v not in index:
            visit(v)
    return found


def _describe(component: frozenset[str], g: dict[str, dict[str, int]]) -> str:
    return "\n".join(f"  {a}:{g[a][b]} imports {b}"
                     for a in sorted(component) for b in sorted(g[a]) if b in component)


def _violations(rule: str) -> dict[Edge, int]:
    """The imports that break ``rule`` → line."""
    out: dict[Edge, int] = {}
    for a, targets in graph().items():
        la = layer(a)
        for b, line in targets.items():
            lb = layer(b)
            if la == lb:
                continue
            bad = {
                "down": LAYER[lb] > LAYER[la],
                "bus": lb in BUS_ONLY.get(la, frozenset()),
                "sim": la in NO_SIM and lb == "sim",
            }[rule]
            if bad:
                out[(a, b)] = line
    return out


def _check(rule: str, why: str) -> None:
    allowed = set(ALLOWED.values())
    found = _violations(rule)
    new = [f"  {a}:{line} imports {b} ({layer(a)} -> {layer(b)})"
           for (a, b), line in sorted(found.items()) if (a, b) not in allowed]
    assert not new, f"{why}:\n" + "\n".join(new)


# ---------------------------------------------------------------- the walker itself
def test_walker_sees_every_kind_of_import() -> None:
    mods = {"sage_robot": True, "sage_robot.x": True, "sage_robot.x.a": False, "sage_robot.x.b": False,
            "sage_robot.x.c": False, "sage_robot.x.d": False, "sage_robot.y": False}
    source = """
from __future__ import annotations
from typing import TYPE_CHECKING
import numpy
import sage_robot.x.a
from sage_robot.x import b, helper
from . import c
from .d import thing
if TYPE_CHECKING:
    from sage_robot.y import Y
def f():
    import sage_robot
"""
    found = imports_of(source, "sage_robot.x.e", False, mods)
    assert set(found) == {"sage_robot.x.a", "sage_robot.x.b", "sage_robot.x", "sage_robot.x.c",
                          "sage_robot.x.d", "sage_robot.y", "sage_robot"}
    assert found["sage_robot.y"] == 10  # under TYPE_CHECKING


def test_cycle_finder() -> None:
    g = {"p.a": {"p.b": 1}, "p.b": {"p.c": 1}, "p.c": {"p.a": 1}, "p.d": {"p.a": 1}, "q.e": {"p.d": 1}}
    assert cycles(g, "p") == [frozenset({"p.a", "p.b", "p.c"})]
    assert cycles({"p.a": {"p.b": 1}, "p.b": {}}, "p") == []


def test_the_graph_is_read() -> None:
    g = graph()
    assert len(g) > 100
    assert "sage_robot.nav.likelihood" in g["sage_robot.nav.amcl_global"]
    assert "sage_robot.nav.drive_host" in g["sage_robot.nav.drive"]  # a TYPE_CHECKING import


# ---------------------------------------------------------------- the rules
def test_every_package_has_a_layer() -> None:
    packages = {layer(m) for m in modules()}
    assert packages <= set(LAYER), f"place these packages in LAYER: {sorted(packages - set(LAYER))}"


def test_imports_point_down_the_layers() -> None:
    _check("down", "imports that point up the layers of ARCHITECTURE.md (core imports nothing of the "
                   "project; nav/kb/voice/brain/hardware/sim never web/app/cli/bench; web never "
                   "app/cli/bench)")


def test_brain_and_web_reach_nav_and_kb_over_the_bus() -> None:
    _check("bus", "brain and web import nav or kb (use bus services, actions and core messages)")


def test_only_the_launch_layer_picks_the_simulator() -> None:
    _check("sim", "modules above sim/hardware import sim (the launcher hands devices in)")


def test_allowlist_is_current() -> None:
    found = _violations("down") | _violations("bus") | _violations("sim")
    stale = [name for name, edge in ALLOWED.items() if edge not in found]
    assert not stale, f"these ALLOWED entries no longer happen; remove them: {stale}"


def test_no_import_cycles_in_nav() -> None:
    g = graph()
    found = cycles(g, "sage_robot.nav")
    assert not found, "import cycles in sage_robot.nav:\n" + "\n\n".join(_describe(c, g) for c in found)


def test_no_new_import_cycles() -> None:
    g = graph()
    found = cycles(g)
    known = set(KNOWN_CYCLES.values())
    new = [c for c in found if c not in known]
    assert not new, "new import cycles:\n" + "\n\n".join(_describe(c, g) for c in new)
    stale = [name for name, c in KNOWN_CYCLES.items() if c not in found]
    assert not stale, f"these KNOWN_CYCLES are gone or changed; update or remove them: {stale}"
