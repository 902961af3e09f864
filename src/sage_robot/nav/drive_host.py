"""What a :class:`~sage_robot.nav.drive.GoalRun` needs of the node that runs it.

``GoalRun`` drives one goal on behalf of a node: it reads the pose, the latest scan, the
costmaps and the localization health, sends velocity commands and events, and publishes its
state and plan. :class:`DriveHost` lists exactly that, so ``drive`` depends on this small
protocol and never on :class:`~sage_robot.nav.navigator.NavigatorNode` (which satisfies it
structurally: mypy checks it where the navigator hands itself to ``GoalRun``). A test can
drive a ``GoalRun`` with any object that has these members.

Data members are read-only properties here: ``GoalRun`` never assigns them (a plain
attribute of the same type satisfies a read-only property).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    import numpy as np

    from sage_robot.core.bus import Bus
    from sage_robot.core.clock import Clock
    from sage_robot.core.config import Settings
    from sage_robot.core.log import StructLogger
    from sage_robot.core.msgs import LaserScan
    from sage_robot.core.msgs.nav import LocalizationHealth, NavigateFeedback
    from sage_robot.nav.costmap import Costmap

Pose = tuple[float, float, float]


class DriveHost(Protocol):
    """The node a :class:`~sage_robot.nav.drive.GoalRun` drives for (the navigator)."""

    # ---------------------------------------------------------------- wiring
    @property
    def settings(self) -> Settings:
        """``nav`` (controller, replan, people wait, relocalization) and ``robot`` (speed limits)."""

    @property
    def clock(self) -> Clock:
        """All of GoalRun's time, sleeps and offloaded planning."""

    @property
    def bus(self) -> Bus:
        """For the global-localization service call while relocalizing."""

    @property
    def log(self) -> StructLogger: ...

    # ---------------------------------------------------------------- what the node sees
    @property
    def scan(self) -> LaserScan | None:
        """The latest scan, taken on the event loop and handed to the planning job."""

    @property
    def health(self) -> LocalizationHealth | None: ...

    @property
    def global_cm(self) -> Costmap:
        """Planned on in a worker thread (offloaded through the clock)."""

    @property
    def local_cm(self) -> Costmap | None:
        """The rolling costmap of the live scan: the controller's forward check."""

    def pose(self) -> Pose | None:
        """The robot's pose in the map; None until localized."""

    def lost(self) -> bool: ...

    def refresh_global(self, pose: Pose | None, scan: LaserScan | None) -> None:
        """Mark ``scan`` taken at ``pose`` into :attr:`global_cm` (called in the worker thread)."""

    # ---------------------------------------------------------------- what the node does
    def command(self, v: float, w: float) -> float: ...  # returns the forward speed sent

    def stop(self) -> None: ...

    def event(self, kind: str, message: str, **data: str) -> None: ...

    def set_state(self, fb: NavigateFeedback) -> None: ...

    def publish_plan(self, points: np.ndarray) -> None: ...

    def clear_costmaps(self) -> None: ...
