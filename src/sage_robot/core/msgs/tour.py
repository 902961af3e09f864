"""Tours planned for a visitor: the plan, its request, the runner's commands and its state.

The brain's ``tour`` node plans (``/sage/tour/plan``: :class:`TourRequest` → :class:`TourPlan`),
runs a plan as consecutive ``navigate_to`` goals, takes commands (``/sage/tour/control``:
:class:`TourCommand` → :class:`TourState`) and publishes its state, latched, on
``/sage/tour`` (:class:`TourState`), which the face and teleop pages show.
"""

from __future__ import annotations

from enum import Enum

from sage_robot.core.msgs.base import message


class TourPhase(str, Enum):
    IDLE = "idle"  # no tour
    DRIVING = "driving"  # on the way to stop ``index``
    AT_STOP = "at_stop"  # dwelling at stop ``index``
    PAUSED = "paused"  # standing still; ``resume`` goes on to stop ``index``
    DONE = "done"  # every stop visited or skipped
    STOPPED = "stopped"  # ended early (``reason`` says why)


TOUR_COMMANDS = ("start", "pause", "resume", "skip", "stop")


@message()
class TourStop:
    """One stop of a plan: the leg that reaches it (from the previous stop or the robot)."""

    name: str
    title: str = ""  # what pages call it
    leg_m: float = 0.0  # path length of the leg (m)
    leg_s: float = 0.0  # driving time of the leg (s)
    why: str = ""  # the interest it answers ("labs", "robots"), "" when named


@message()
class TourRequest:
    """What the visitor asked for: interests in words and/or named places, and a time budget."""

    interests: str = ""
    places: tuple[str, ...] = ()  # named places; kept, in route order
    budget_s: float = 0.0  # 0 = no limit (the plan keeps at most its maximum number of stops)


@message()
class TourPlan:
    """A plan in route order; ``estimate_s`` = driving + dwelling; ``ok`` False with ``reason``."""

    ok: bool
    stops: tuple[TourStop, ...] = ()
    estimate_s: float = 0.0
    drive_m: float = 0.0
    dwell_s: float = 0.0  # per stop
    budget_s: float = 0.0
    dropped: tuple[str, ...] = ()  # places that fitted the request but not the budget
    distances: str = ""  # "map" (path lengths on the map) or "straight-line"
    reason: str = ""


@message()
class TourCommand:
    """``start`` (with ``places`` in order), ``pause``, ``resume``, ``skip`` or ``stop``."""

    command: str
    places: tuple[str, ...] = ()
    budget_s: float = 0.0
    estimate_s: float = 0.0
    by: str = ""  # who asked: "brain" (its reply says what happens), "operator", "visitor"


@message()
class TourState:
    """The runner's state (latched). ``index`` is the current stop (-1 before the first)."""

    phase: TourPhase = TourPhase.IDLE
    stops: tuple[str, ...] = ()
    titles: tuple[str, ...] = ()
    index: int = -1
    visited: tuple[str, ...] = ()
    skipped: tuple[str, ...] = ()
    estimate_s: float = 0.0  # the plan's estimate at the start
    budget_s: float = 0.0
    started_at: float = 0.0  # clock time the tour started
    reason: str = ""  # why it paused or stopped
    ok: bool = True  # False: the command that answered with this state was refused (``reason``)
