"""The battery watchdog: warn and critical levels with hysteresis, events, and e-mail.

The seed's watchdog e-mailed on low voltage through the knowledge-base service. Ours
reads ``/battery_state``, moves between OK → WARN → CRITICAL with a hysteresis band (a
jittering voltage does not flap or storm), publishes ``battery_low`` /
``battery_critical`` / ``battery_ok`` events (the brain tells the visitor it must go back
to its dock; the operator page shows the event) and sends at most one e-mail per level
per ``email.min_interval_s``, retried in the background — a dead mail server never
stops the node.

A reading with an unknown charge (NaN: firmware that reports no battery, such as the seed
robot's current one) changes no level; the first one is logged once as a warning and
published as a ``battery_unknown`` event, so nobody mistakes silence for a full battery.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable
from enum import Enum
from typing import Any

from sage_robot.core import topics
from sage_robot.core.msgs import BatteryState, Event
from sage_robot.core.node import Node

MAIL_RETRIES = 3
MAIL_RETRY_BASE_S = 2.0  # 2 s, 4 s, 8 s between attempts


class BatteryLevel(str, Enum):
    OK = "ok"
    WARN = "warn"
    CRITICAL = "critical"


EVENT_KIND = {
    BatteryLevel.OK: "battery_ok",
    BatteryLevel.WARN: "battery_low",
    BatteryLevel.CRITICAL: "battery_critical",
}


class BatteryMonitor:
    """Pure level logic. Enter a worse level below its threshold; leave it only above
    threshold + hysteresis."""

    def __init__(self, warn: float, critical: float, hysteresis: float) -> None:
        if not 0 <= critical < warn <= 1:
            raise ValueError("need 0 <= critical < warn <= 1")
        self.warn, self.critical, self.hysteresis = warn, critical, hysteresis
        self.level = BatteryLevel.OK

    def update(self, fraction: float) -> BatteryLevel | None:
        """Feed a charge fraction (0..1); returns the new level when it changed."""
        if math.isnan(fraction):
            return None
        old = self.level
        if fraction < self.critical:
            new = BatteryLevel.CRITICAL
        elif fraction < self.warn:
            leaving_critical = fraction > self.critical + self.hysteresis
            new = (
                BatteryLevel.CRITICAL
                if old is BatteryLevel.CRITICAL and not leaving_critical
                else BatteryLevel.WARN
            )
        elif old is BatteryLevel.OK or fraction > self.warn + self.hysteresis:
            new = BatteryLevel.OK
        else:
            new = BatteryLevel.WARN
        self.level = new
        return new if new is not old else None


MailSender = Callable[[str, str], Awaitable[bool]]  # (subject, body) -> sent?


def default_mailer(node: Node) -> MailSender | None:
    """SMTP from the profile's email section, or None when no server is configured."""
    email = node.settings.email
    if not email.smtp_host or not email.recipients:
        return None
    from sage_robot.kb.mail import send_mail_async

    async def send(subject: str, body: str) -> bool:
        # One attempt per call: the watchdog retries on its own clock.
        result = await send_mail_async(
            email, subject, body, key_file=node.settings.secrets_file or None, attempts=1
        )
        if not result.ok:
            node.log.warning("battery e-mail not sent", error=result.error)
        return result.ok

    return send


class BatteryWatchdogNode(Node):
    name = "battery_watchdog"

    def __init__(self, ctx: Any, mailer: MailSender | None = None) -> None:
        super().__init__(ctx)
        b = self.settings.battery
        self.monitor = BatteryMonitor(b.warn_fraction, b.critical_fraction, b.hysteresis_fraction)
        self._mailer = mailer
        self._last_mail: dict[BatteryLevel, float] = {}
        self.mails_sent = 0
        self.mails_failed = 0
        self.last_state: BatteryState | None = None
        self.unknown_warned = False

    async def setup(self) -> None:
        if self._mailer is None:
            self._mailer = default_mailer(self)
        self.subscribe(topics.BATTERY, BatteryState, self._on_battery)

    def _on_battery(self, msg: BatteryState) -> None:
        self.last_state = msg
        if math.isnan(msg.percentage):
            self._warn_unknown()
            return
        changed = self.monitor.update(msg.percentage)
        if changed is None:
            return
        pct = f"{msg.percentage * 100:.0f}%"
        text = {
            BatteryLevel.OK: f"Battery back to {pct} ({msg.voltage:.2f} V).",
            BatteryLevel.WARN: f"Battery low: {pct} ({msg.voltage:.2f} V).",
            BatteryLevel.CRITICAL: f"Battery critical: {pct} ({msg.voltage:.2f} V); "
            "the robot must return to its dock.",
        }[changed]
        self.log.warning(
            "battery level changed", level=changed.value, charge=pct, volts=round(msg.voltage, 2)
        )
        self.bus.publish(
            topics.EVENTS,
            Event(
                self.clock.now(),
                self.name,
                EVENT_KIND[changed],
                text,
                {"percentage": f"{msg.percentage:.3f}", "voltage": f"{msg.voltage:.2f}"},
            ),
        )
        if changed is not BatteryLevel.OK:
            self._maybe_mail(changed, text)

    def _warn_unknown(self) -> None:
        if self.unknown_warned:
            return
        self.unknown_warned = True
        text = "No battery readings: the battery level is unknown (the MCU firmware reports none)."
        self.log.warning(text)
        self.bus.publish(topics.EVENTS, Event(self.clock.now(), self.name, "battery_unknown", text))

    def _maybe_mail(self, level: BatteryLevel, text: str) -> None:
        if self._mailer is None:
            return
        now = self.clock.now()
        last = self._last_mail.get(level)
        if last is not None and now - last < self.settings.email.min_interval_s:
            return
        self._last_mail[level] = now
        robot = self.settings.robot.name
        self.spawn(self._send_with_retries(f"[{robot}] {text.split(':')[0]}", f"{robot}: {text}"))

    async def _send_with_retries(self, subject: str, body: str) -> None:
        assert self._mailer is not None
        for attempt in range(MAIL_RETRIES):
            try:
                if await self._mailer(subject, body):
                    self.mails_sent += 1
                    return
            except Exception as exc:  # a mail server problem must never stop the watchdog
                self.log.warning("battery e-mail failed", attempt=attempt + 1, error=str(exc))
            await self.clock.sleep(MAIL_RETRY_BASE_S * 2**attempt)
        self.mails_failed += 1
        self.log.error("battery e-mail gave up", subject=subject)

    async def run(self) -> None:
        # Mail tasks may finish or fail on their own; only a broken subscription ends the node.
        await asyncio.Event().wait()

    def stats(self) -> dict[str, Any]:
        unknown = self.last_state is None or math.isnan(self.last_state.percentage)
        return {
            "level": "unknown" if unknown else self.monitor.level.value,
            "mails_sent": self.mails_sent,
            "mails_failed": self.mails_failed,
        }
