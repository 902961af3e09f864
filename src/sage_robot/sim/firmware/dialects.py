"""The firmware dialects the simulator can run, by the name ``mcu.firmware`` takes in the
profile, and the interface every firmware model offers the pty, the nodes and the benches.

- ``documented``: :class:`FirmwareModel`, the seed document's framed protocol (0x7E CMD,
  watchdog, BATTERY frames; docs/mcu.md).
- ``seed-2025``: :class:`Seed2025Model`, what the seed robot's STM32 runs today (9-byte
  0x78 blocks, no watchdog, no BATTERY, signed theta; docs/sim.md).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Protocol

import numpy as np

from sage_robot.sim.firmware.model import FirmwareModel
from sage_robot.sim.firmware.params import FirmwareParams
from sage_robot.sim.firmware.seed2025 import Seed2025Model
from sage_robot.sim.firmware.seed2025_params import Seed2025Params


class RxCounters(Protocol):
    @property
    def frames(self) -> int:
        """Commands accepted."""
        ...

    @property
    def errors(self) -> Counter[str]:
        """Rejected input, by kind."""
        ...


class TrackParams(Protocol):
    @property
    def track_width_m(self) -> float: ...


class SimFirmware(Protocol):
    """What :class:`PtyMcu`, ``McuSimNode``, ``RealTimeMcu`` and the tests use."""

    frames_sent: Counter[str]
    watchdog_trips: int

    @property
    def params(self) -> TrackParams: ...

    @property
    def rx(self) -> RxCounters: ...

    @property
    def odom_pose(self) -> tuple[float, float, float]: ...

    @property
    def pwm_us(self) -> tuple[float, float]: ...

    @property
    def wheel_speeds(self) -> tuple[float, float]: ...

    @property
    def battery_voltage(self) -> float: ...

    @property
    def watchdog_tripped(self) -> bool: ...

    @property
    def last_command_t(self) -> float | None: ...

    @property
    def last_command(self) -> tuple[float, float]: ...

    @property
    def stopped(self) -> bool: ...

    def receive(self, data: bytes) -> None: ...

    def control_step(self, dt: float, now: float) -> tuple[float, float]: ...

    def sense(self, dt: float, v_true: float, w_true: float) -> None: ...

    def transmit(self, now: float) -> bytes: ...


# (the profile's robot.track_width_m, seeded generator) -> a firmware model
FirmwareFactory = Callable[[float, np.random.Generator], SimFirmware]


def _documented(track_width_m: float, rng: np.random.Generator) -> SimFirmware:
    return FirmwareModel(FirmwareParams(track_width_m=track_width_m), rng)


def _seed_2025(track_width_m: float, rng: np.random.Generator) -> SimFirmware:
    # The track is compiled into this firmware (0.483 m): the profile's value is the
    # body's, not the firmware's, so it is not passed on (McuSimNode warns on a mismatch).
    return Seed2025Model(Seed2025Params(), rng)


FIRMWARE_DIALECTS: dict[str, FirmwareFactory] = {
    "documented": _documented,
    "seed-2025": _seed_2025,
}


def make_firmware(dialect: str, track_width_m: float, rng: np.random.Generator) -> SimFirmware:
    """The firmware model for ``mcu.firmware``; ValueError names the known dialects."""
    factory = FIRMWARE_DIALECTS.get(dialect)
    if factory is None:
        known = ", ".join(sorted(FIRMWARE_DIALECTS))
        raise ValueError(f"unknown MCU firmware dialect {dialect!r}; known: {known}")
    return factory(track_width_m, rng)
