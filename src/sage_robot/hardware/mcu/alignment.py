"""Noticing that a block-aligned firmware (seed-2025) no longer reads SAGE's commands.

The seed-2025 firmware receives commands in fixed 9-byte blocks; after a lost or extra
byte, or a reboot mid-stream, its blocks start inside SAGE's frames and every command is
dropped while the *last applied one keeps running* (it has no watchdog). Nothing on the
wire says so; the robot's own odometry does:

- SAGE commands motion and odometry stays still for :data:`SETTLE_S` → ``"step"``: write
  one filler byte (shifts the firmware's alignment by one; at most 8 steps realign it);
- SAGE commands a stop and odometry keeps moving for :data:`STOP_SETTLE_S` → ``"stop"``:
  write the stop burst again (applied whatever the alignment). The first burst already
  was; this is the backstop for bytes lost on the way.
- Odometry runs away — faster than the profile ever commands, or backwards when SAGE never
  reverses — for :data:`RUNAWAY_S` → ``"stop"`` at once. This is the one harm a misaligned
  seed-2025 firmware can still do: a byte lost *inside* a frame shifts the next header into
  the payload of the block before it, and that firmware applies any float with no range
  check. No encoding on SAGE's side can prevent that (a one-line range check in the
  firmware would); SAGE stops it within about 0.1 s plus the firmware's braking.

A robot that really cannot move (pushing a wall) triggers steps that only cost a few
dropped commands; the stop is never delayed. Pure: no I/O, times in seconds of any clock.
"""

from __future__ import annotations

from typing import Literal

SETTLE_S = 0.5  # a moving command with still odometry must last this long (s)
RUNAWAY_S = 0.1  # odometry beyond the limits this long: a wild command ran (s)
RUNAWAY_MARGIN_MPS, RUNAWAY_MARGIN_RADPS = 0.1, 0.5  # above the profile's limits
STOP_SETTLE_S = 0.8  # a stop with moving odometry (braking from 0.8 m/s takes ~0.6 s) (s)
STEP_EVERY_S = 0.3  # and then one action per this period (s): odometry needs time to answer
CMD_MOVING_MPS, CMD_MOVING_RADPS = 0.05, 0.1  # a command this fast should show in odometry
ODOM_STILL_MPS, ODOM_STILL_RADPS = 0.01, 0.02  # odometry below both: the robot is still
ODOM_MOVING_MPS, ODOM_MOVING_RADPS = 0.03, 0.05  # odometry above either: the robot moves

Action = Literal["", "step", "stop"]


class AlignmentWatch:
    def __init__(self, settle_s: float = SETTLE_S, stop_settle_s: float = STOP_SETTLE_S,
                 step_every_s: float = STEP_EVERY_S,
                 limits: tuple[float, float, bool] = (1.0, 3.0, False)) -> None:
        """``limits``: the profile's (max v m/s, max w rad/s, reverse allowed)."""
        self.settle_s, self.stop_settle_s, self.step_every_s = settle_s, stop_settle_s, step_every_s
        self.limits = limits
        self._runaway_since: float | None = None
        self.runaways = 0  # wild motion seen and stopped
        self._mismatch_since: float | None = None
        self._last_action = float("-inf")
        self.steps = 0  # filler bytes asked for
        self.stops = 0  # stop bursts asked for again

    def _runaway(self, odom: tuple[float, float], now: float) -> bool:
        if not _runaway_motion(odom, self.limits):
            self._runaway_since = None
            return False
        if self._runaway_since is None:
            self._runaway_since = now
        if now - self._runaway_since < RUNAWAY_S or now - self._last_action < self.step_every_s:
            return False
        self._last_action = now
        self.runaways += 1
        self.stops += 1
        return True

    def reset(self) -> None:
        """The command changed or the link was reopened: judge afresh."""
        self._mismatch_since = None

    def update(self, command: tuple[float, float], odom: tuple[float, float] | None, now: float) -> Action:
        """The latest command and odometry twist (v m/s, w rad/s): what to do now."""
        if odom is None:
            return ""
        if self._runaway(odom, now):
            return "stop"
        kind = _mismatch(command, odom)
        if not kind:
            self._mismatch_since = None
            return ""
        if self._mismatch_since is None:
            self._mismatch_since = now
        settle = self.stop_settle_s if kind == "stop" else self.settle_s
        if now - self._mismatch_since < settle or now - self._last_action < self.step_every_s:
            return ""
        self._last_action = now
        if kind == "stop":
            self.stops += 1
        else:
            self.steps += 1
        return kind


def _runaway_motion(odom: tuple[float, float], limits: tuple[float, float, bool]) -> bool:
    max_v, max_w, reverse = limits
    v, w = odom
    too_fast = abs(v) > max_v + RUNAWAY_MARGIN_MPS or abs(w) > max_w + RUNAWAY_MARGIN_RADPS
    return too_fast or (not reverse and v < -RUNAWAY_MARGIN_MPS)


def _mismatch(command: tuple[float, float], odom: tuple[float, float]) -> Action:
    v, w = command
    ov, ow = abs(odom[0]), abs(odom[1])
    if (v, w) == (0.0, 0.0):
        return "stop" if ov >= ODOM_MOVING_MPS or ow >= ODOM_MOVING_RADPS else ""
    if abs(v) >= CMD_MOVING_MPS or abs(w) >= CMD_MOVING_RADPS:
        return "step" if ov < ODOM_STILL_MPS and ow < ODOM_STILL_RADPS else ""
    return ""
