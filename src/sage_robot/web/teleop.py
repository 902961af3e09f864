"""Teleoperation: operator commands -> ``/cmd_vel``, with a deadman and a latching e-stop.

- A control message ``{"type": "control", "x": m/s, "z": rad/s}`` is validated, clamped
  to the robot's limits and published as a Twist at once (no batching: the key-to-motor
  latency is what an operator feels).
- **Deadman**: the page repeats a held command every :data:`CLIENT_REPEAT_S`; if no
  control message arrives for ``web.deadman_s`` while the last command was non-zero, a
  zero Twist is published. Closing the socket of the operator who drove last publishes
  a zero Twist at once. The deadman runs on wall time on purpose: it guards against a
  network that went quiet, which happens in real seconds even when the simulator runs
  faster than real time.
- **E-stop** latches: engaging it publishes a zero Twist *first*, then the latched
  ``/sage/estop`` state, then asks navigation to stop. While engaged every control message
  is refused with an error reply and a goal someone else (the brain, a tour) starts
  meanwhile is cancelled within :data:`DEADMAN_CHECK_S`. Only an explicit
  ``{"type": "estop", "engaged": false}`` from a logged-in operator releases it.
- **Nothing here waits on navigation.** The deadman loop and the e-stop only *request*
  cancels (:meth:`GoalHandle.request_cancel`); the cancel service is called from a task of
  its own with a bound, so a navigator that hangs can never hold up a stop. The serial
  bridge's own command timeout (``mcu.cmd_timeout_s``) is a third, independent layer.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from typing import Any

from sage_robot.core import topics
from sage_robot.core.actions import CANCEL_WAIT_S, GoalTimeout
from sage_robot.core.log import get_logger
from sage_robot.core.msgs import EStopState, Event, Twist
from sage_robot.core.msgs.nav import NavState
from sage_robot.core.node import Node

CLIENT_REPEAT_S = 0.1  # the page re-sends a held command this often (s); documented for pages
DEADMAN_CHECK_S = 0.02  # how often the deadman (and the e-stop hold) looks while it has work (s)
DEADMAN_IDLE_S = 1.0  # no command, no e-stop: nothing to check; a bound, or at the next command (s)
CANCEL_SERVICE_TIMEOUT_S = 1.0  # the e-stop's call of the navigator's cancel service (s)
ESTOP_RECANCEL_S = 0.5  # while engaged, the cancel service is asked again this often if nav still runs (s)
NAV_ACTIONS = (topics.NAVIGATE_TO, topics.TOUR)  # what the e-stop cancels
# the navigator's states while it follows a goal (the e-stop asks it to cancel)
GOAL_STATES = frozenset(
    {NavState.PLANNING, NavState.DRIVING, NavState.WAITING_FOR_PEOPLE, NavState.RECOVERING}
)
MAX_CONTROL_INT = 10**6  # a JSON integer beyond this is no speed (and may not fit a float)

_log = get_logger("web")


class BadMessage(ValueError):
    """A client message that cannot be used; the text goes back to the client."""


def parse_control(msg: dict[str, Any]) -> tuple[float, float]:
    """``x`` (m/s) and ``z`` (rad/s) from a control message; finite numbers only."""
    out = []
    for key in ("x", "z"):
        value = msg.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise BadMessage(f"control: {key!r} must be a number, got {value!r}")
        if isinstance(value, int) and abs(value) > MAX_CONTROL_INT:
            raise BadMessage(f"control: {key!r} is out of range, got a {len(str(abs(value)))}-digit number")
        if not math.isfinite(value):
            raise BadMessage(f"control: {key!r} must be finite, got {value!r}")
        out.append(float(value))
    return out[0], out[1]


class Teleop:
    """Shared by every teleop socket of the web node (the last operator to send drives)."""

    def __init__(self, node: Node, hub: Any) -> None:
        self.node, self.hub = node, hub
        self.bus, self.clock = node.bus, node.clock
        robot = node.settings.robot
        self.max_v, self.max_w = robot.max_linear_mps, robot.max_angular_radps
        self.deadman_s = node.settings.web.deadman_s
        self.command = (0.0, 0.0)
        self.last_control = 0.0  # time.monotonic() of the last control message
        self.driver: object | None = None
        self.counts = {
            "controls": 0, "deadman_stops": 0, "close_stops": 0, "refused": 0, "estop_cancels": 0,
        }  # fmt: skip
        self._estop_cancel_at = -math.inf  # time.monotonic() of the hold's last cancel-service call
        self._armed = asyncio.Event()  # a command or the e-stop: the deadman looks closely again

    def start(self) -> None:
        self.bus.declare(topics.ESTOP, EStopState, latched=True)
        self.bus.publish(topics.ESTOP, EStopState(bool(self.hub.estop), ""))
        self.node.spawn(self._deadman_loop(), "web.deadman")

    @property
    def estop(self) -> bool:
        return bool(self.hub.estop)

    def control(self, client: object, x: float, z: float) -> tuple[float, float]:
        """Apply a command from ``client``; raises BadMessage while the e-stop is engaged."""
        if self.estop:
            self.counts["refused"] += 1
            self._publish(0.0, 0.0)
            raise BadMessage("e-stop is engaged: release it before driving")
        v = max(-self.max_v, min(self.max_v, x))
        w = max(-self.max_w, min(self.max_w, z))
        self.driver, self.last_control = client, time.monotonic()
        self.counts["controls"] += 1
        self._publish(v, w)
        return v, w

    def release_client(self, client: object) -> None:
        """The socket of ``client`` closed: stop if it was driving."""
        if self.driver is client:
            self.driver = None
            if self.command != (0.0, 0.0):
                self.counts["close_stops"] += 1
                _log.info("teleop socket closed while driving: stopping")
            self._publish(0.0, 0.0)

    async def set_estop(self, engaged: bool, who: str) -> None:
        """Engage or release the e-stop; returns at once (it never waits for navigation)."""
        if engaged == self.estop:
            return
        if engaged:
            self._publish(0.0, 0.0)  # the wire first: nothing below may delay this
        self.hub.estop = engaged
        self._armed.set()
        self.bus.publish(topics.ESTOP, EStopState(engaged, who))
        self.hub.set("estop", {"type": "estop", "engaged": engaged})
        self.bus.publish(
            topics.EVENTS,
            Event(self.clock.now(), "web", "estop" if engaged else "estop_released", f"by {who}"),
        )
        _log.warning("e-stop engaged" if engaged else "e-stop released", by=who)
        if engaged:
            self.request_cancel_navigation()

    def _hold_estop(self) -> None:
        """While the e-stop is engaged, a goal that anyone starts (the brain, a tour) is cancelled
        at once: the e-stop stops every motion, not only the operator's. A goal this process
        cannot see (sent from another process to the navigator in a third) shows on the
        navigator's latched state: the navigator's cancel service is asked again while it
        says it drives."""
        for action in NAV_ACTIONS:
            active = self.bus.actions.active(action)
            if active is not None and not active.cancel_requested:
                self.counts["estop_cancels"] += 1
                _log.warning("navigation goal during e-stop: cancelled", action=action)
                active.request_cancel()
        if self.command != (0.0, 0.0):
            self._publish(0.0, 0.0)
        nav = self.bus.latest(topics.NAV_STATE)
        now = time.monotonic()
        if (
            nav is not None
            and nav.state in GOAL_STATES
            and now - self._estop_cancel_at >= ESTOP_RECANCEL_S
            and self.bus.has_service(topics.CANCEL_NAV)
        ):
            self._estop_cancel_at = now
            self.counts["estop_cancels"] += 1
            _log.warning("navigator busy during e-stop: cancelling", state=nav.state.value)
            self.node.spawn(self._call_cancel_service(), "web.cancel_nav")

    def request_cancel_navigation(self) -> None:
        """Ask every navigation goal to stop (no waiting), and the navigator's cancel service
        from a task of its own (bounded)."""
        for action in NAV_ACTIONS:
            active = self.bus.actions.active(action)
            if active is not None:
                active.request_cancel()
        if self.bus.has_service(topics.CANCEL_NAV):
            self.node.spawn(self._call_cancel_service(), "web.cancel_nav")

    async def _call_cancel_service(self) -> None:
        try:
            await self.bus.call(topics.CANCEL_NAV, None, timeout=CANCEL_SERVICE_TIMEOUT_S)
        except Exception as exc:  # the goals were already asked to stop; this is the backstop
            _log.warning("navigation cancel service failed", error=str(exc))

    async def cancel_navigation(self) -> None:
        """Stop navigation and wait (bounded) until no goal runs: for the operator's Cancel."""
        handles = [h for a in NAV_ACTIONS if (h := self.bus.actions.active(a)) is not None]
        self.request_cancel_navigation()
        for handle in handles:
            with contextlib.suppress(GoalTimeout):
                await handle.result(CANCEL_WAIT_S)

    def _publish(self, v: float, w: float) -> None:
        self.command = (v, w)
        self.bus.publish(topics.CMD_VEL, Twist(v, w))
        if (v, w) != (0.0, 0.0):
            self._armed.set()

    async def _deadman_loop(self) -> None:
        """Runs until the node stops; every step is synchronous, so nothing can hold it up.
        Every DEADMAN_CHECK_S while a command stands or the e-stop is engaged; at rest every
        DEADMAN_IDLE_S, and a command or the e-stop wakes it at once."""
        while True:
            if self.estop or self.command != (0.0, 0.0):
                await asyncio.sleep(DEADMAN_CHECK_S)
            else:
                self._armed.clear()
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(self._armed.wait(), DEADMAN_IDLE_S)
            if self.estop:
                self._hold_estop()
            silent = time.monotonic() - self.last_control
            if self.command != (0.0, 0.0) and self.driver is not None and silent > self.deadman_s:
                self.counts["deadman_stops"] += 1
                _log.info("deadman: no control message, stopping", silent_s=round(silent, 2))
                self._publish(0.0, 0.0)
                self.hub.set(
                    "teleop", {"type": "deadman", "message": "no command from the operator: stopped"}
                )
