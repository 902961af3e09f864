"""Can the robot drive now? The e-stop, the battery and localization, and the honest words
for when it can not.

Pure: :class:`RobotLink` fills a :class:`Readiness` from what it heard on the bus, and the
navigation tools ask it before a goal is sent. The rules, in order:

1. E-stop engaged → nothing moves (not even to the dock): an operator has to release it.
2. Battery below ``battery.critical_fraction`` (the battery watchdog's critical level,
   10 %) → no tour and no drive, except to the docking station.
3. Battery below ``battery.warn_fraction`` (25 %) → no tour (eight stops is a long
   drive); a single place is still fine.
4. Localization lost (for ``LOST_CONFIRM_S``) → no drive: say so and ask for help.

An unknown battery level (no reading yet, or NaN) is unknown, never 0 % or full: it
refuses nothing and is said as "unknown".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

DOCK = "DOCKING_STATION"
LOST_CONFIRM_S = 1.0  # localization must say "lost" this long before the brain believes it (s)

ESTOP_LINE = "I can't move right now: the emergency stop is on. An operator has to release it."
LOST_LINE = (
    "I can't drive right now: I have lost track of where I am on my map. "
    "An operator can set my position, then I can take you."
)
BATTERY_CRITICAL_LINE = (
    "My battery is nearly empty, at {pct} percent, so I can't {what}. "
    "I have to go back to my docking station."
)
BATTERY_LOW_TOUR_LINE = (
    "My battery is at {pct} percent, too low for a whole tour. I can still take you to one place."
)
NAV_DOWN_LINE = "navigation is not running right now"
TOUR_DOWN_LINE = "the tour guide part of navigation is not running right now"


class Refusal(str, Enum):
    """Why a drive was not started."""

    ESTOP = "estop"
    BATTERY = "battery"
    LOST = "lost"
    NAVIGATION = "navigation"  # not running, or it turned the goal down


@dataclass(frozen=True)
class Readiness:
    """A snapshot of what keeps the robot from driving."""

    estop: bool = False
    estop_by: str = ""
    battery: float | None = None  # 0..1; None = unknown
    lost: bool = False
    battery_critical: float = 0.10
    battery_low: float = 0.25

    @property
    def battery_percent(self) -> int | None:
        """Whole percent, rounded down (9.6 % below a 10 % line is said as 9)."""
        return None if self.battery is None else math.floor(round(100 * self.battery, 6))

    def _critical(self, what: str) -> str:
        return BATTERY_CRITICAL_LINE.format(pct=self.battery_percent, what=what)

    def refuse_drive(self, place: str) -> tuple[Refusal, str] | None:
        """Why a drive to ``place`` must not start, or None when it may."""
        if self.estop:
            return Refusal.ESTOP, ESTOP_LINE
        if self.battery is not None and self.battery < self.battery_critical and place != DOCK:
            return Refusal.BATTERY, self._critical("take you there")
        if self.lost:
            return Refusal.LOST, LOST_LINE
        return None

    def refuse_tour(self) -> tuple[Refusal, str] | None:
        if self.estop:
            return Refusal.ESTOP, ESTOP_LINE
        if self.battery is not None and self.battery < self.battery_critical:
            return Refusal.BATTERY, self._critical("start a tour")
        if self.battery is not None and self.battery < self.battery_low:
            return Refusal.BATTERY, BATTERY_LOW_TOUR_LINE.format(pct=self.battery_percent)
        if self.lost:
            return Refusal.LOST, LOST_LINE
        return None

    def describe(self) -> str:
        """For the system prompt: e-stop, battery and localization in a few words."""
        by = self.estop_by or "an operator"
        estop = f"ENGAGED by {by}, the robot can not move" if self.estop else "off"
        if self.battery is None:
            battery = "unknown"
        else:
            battery = f"{self.battery_percent} percent"
            if self.battery < self.battery_critical:
                battery += " (critically low: only the docking station)"
            elif self.battery < self.battery_low:
                battery += " (low: no tours)"
        where = "LOST, needs an operator to set its position" if self.lost else "ok"
        return f"emergency stop {estop}; battery {battery}; localization {where}"
