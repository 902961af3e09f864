"""Navigation interfaces: the ``navigate_to`` and ``tour`` actions, places, localization health.

Owned by the navigation area; the brain and the web reach navigation only through these.
"""

from __future__ import annotations

from enum import Enum

from sage_robot.core.msgs.base import message
from sage_robot.core.msgs.std import Pose2D


class NavState(str, Enum):
    IDLE = "idle"
    PLANNING = "planning"
    DRIVING = "driving"
    WAITING_FOR_PEOPLE = "waiting_for_people"
    RECOVERING = "recovering"
    LOST = "lost"


@message()
class NavigateGoal:
    """Go to a place by name/alias (fuzzy) or to a pose in the map frame. Exactly one is set."""

    place: str = ""
    pose: Pose2D | None = None


@message()
class NavigateFeedback:
    state: NavState
    place: str = ""  # canonical place name, "" for a pose goal
    distance_remaining_m: float = 0.0
    eta_s: float = 0.0


@message()
class NavigateResult:
    """``reason`` is for a person ("the corridor to the clean room is blocked")."""

    succeeded: bool
    place: str = ""
    reason: str = ""
    distance_travelled_m: float = 0.0
    duration_s: float = 0.0


@message()
class TourGoal:
    """An ordered list of place names; dwell at each for ``dwell_s`` seconds."""

    places: tuple[str, ...]
    dwell_s: float = 10.0
    start_index: int = 0  # resume an interrupted tour here


@message()
class TourFeedback:
    index: int
    place: str
    state: NavState


@message()
class TourResult:
    completed: tuple[str, ...]
    succeeded: bool
    reason: str = ""


@message()
class PlaceInfo:
    name: str
    pose: Pose2D
    description: str = ""
    aliases: tuple[str, ...] = ()


@message()
class PlaceList:
    places: tuple[PlaceInfo, ...] = ()


@message()
class WhereAmI:
    """Answer of the where-am-i service: nearest place and distance to it."""

    pose: Pose2D
    nearest_place: str
    distance_m: float
    localized: bool


@message()
class LocalizationHealth:
    """How well the current scan fits the map (0..1), not just covariance."""

    stamp: float
    score: float
    lost: bool
    particles: int = 0
    spread_m: float = 0.0  # cloud spread (m), or distance to the farthest other hypothesis; small = converged
    hypotheses: int = 1  # places the particle cloud still considers (look-alike corridors); 1 = unambiguous
