"""Process groups: which nodes share an operating-system process (``sage sim --processes``).

Each group runs as its own process under one supervisor (``sage_robot.app.process_groups``)
that restarts a crashed group with backoff; the groups talk over Zenoh on loopback. A group
lists node names; nodes a mode does not run are ignored, so one grouping serves every mode.
A node may be in one group only (checked here); that every node of a mode is in some group
is checked when the mode's groups are planned (the registry knows the nodes, core does not).
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from pydantic import Field, field_validator

from sage_robot.core.config.base import Section
from sage_robot.core.errors import ConfigError

GROUP_NAME = re.compile(r"^[a-z][a-z0-9_]{0,31}$")  # a group name: also a topic-name chunk
CLOCK_GROUP = "sim"  # the group whose simulated clock the others follow (it publishes /clock)

# The default split: the motion process is small (no ML imports) and restarts fast; what
# shares in-process objects stays together (the world and the firmware model; the KB service
# and the brain that asks it).
DEFAULT_GROUPS: dict[str, tuple[str, ...]] = {
    "sim": ("sim_world", "mcu_sim"),
    "motion": ("serial_bridge", "battery_watchdog", "heartbeat"),
    "sensors": ("lidar", "camera"),
    "nav": ("map_server", "localization", "navigator", "slam"),
    "voice": ("voice",),
    "brain": ("kb", "brain", "tour"),
    "web": ("web", "foxglove", "ros2_bridge", "recorder", "replay"),
}


# Niceness by group (Linux nice, 0..19): speech and the brain's models (Whisper, Piper, the
# embeddings; a restart's imports) yield the cores to motion, navigation and the pages when
# the machine is busy.
DEFAULT_NICE: dict[str, int] = {"voice": 5, "brain": 5}
MAX_NICE = 19

# Real-time priority by group (Linux SCHED_FIFO, 1..99): the motion process (serial bridge,
# dead-man) is small and mostly asleep, and a /cmd_vel or a stop must reach it within a couple
# of milliseconds whatever the rest of the robot is doing (sage_robot.core.realtime). 40 stays
# below the kernel's threaded interrupt handlers (50 on PREEMPT_RT kernels, as the Jetson's
# can be), so the serial port's interrupts still come first.
DEFAULT_REALTIME: dict[str, int] = {"motion": 40}
MAX_REALTIME = 99

# Real-time priority of Zenoh's network threads in every group (SCHED_FIFO; 0: normal). A
# message a normal-priority node publishes (the navigator's or the web's /cmd_vel) is written
# to the socket by one of these threads: under the normal scheduler, beside the busy robot on
# two cores, it waited for a time slice (1 kHz /cmd_vel p99 0.9-1.9 ms, 3.7-5.1 ms with both
# cores busy); raised, it goes at once (0.6-0.9 ms; 1.3-2.7 ms). Their work per message is
# short (a copy to a socket, a frame decoded and queued for the node's loop). 10 stays below
# the motion process's 40, whose own Zenoh threads keep its priority.
DEFAULT_ZENOH_REALTIME = 10


class ProcessSettings(Section):
    groups: dict[str, tuple[str, ...]] = Field(
        default_factory=lambda: dict(DEFAULT_GROUPS),
        description="Group name -> the nodes that run in that process. A group named "
        f"'{CLOCK_GROUP}' runs the simulator and publishes /clock; the others follow it.",
    )
    nice: dict[str, int] = Field(
        default_factory=lambda: dict(DEFAULT_NICE),
        description="Group name -> how much lower its CPU priority is (Linux nice, 0-19; "
        "groups not named run at 0). Under load the cores go to the other groups first.",
    )
    realtime: dict[str, int] = Field(
        default_factory=lambda: dict(DEFAULT_REALTIME),
        description="Group name -> its real-time priority (Linux SCHED_FIFO, 1-99): it preempts "
        "every normal process when it wakes. Only for small groups that are mostly asleep. Needs "
        "CAP_SYS_NICE or LimitRTPRIO; without it the group runs at the normal priority and says so.",
    )

    zenoh_realtime: int = Field(
        DEFAULT_ZENOH_REALTIME,
        ge=0,
        le=MAX_REALTIME,
        description="Real-time priority (Linux SCHED_FIFO, 1-99; 0: normal) of Zenoh's network "
        "threads in every group, so a message leaves or arrives without waiting for a busy "
        "core's time slice. Groups at a higher processes.realtime keep theirs. Needs "
        "CAP_SYS_NICE or LimitRTPRIO; without it the threads stay normal and the group says so.",
    )

    @field_validator("nice")
    @classmethod
    def _nice_range(cls, nice: dict[str, int]) -> dict[str, int]:
        for group, value in nice.items():
            if not 0 <= value <= MAX_NICE:
                raise ValueError(f"nice of group {group!r}: {value} is not in 0..{MAX_NICE}")
        return nice

    @field_validator("realtime")
    @classmethod
    def _realtime_range(cls, realtime: dict[str, int]) -> dict[str, int]:
        for group, value in realtime.items():
            if not 1 <= value <= MAX_REALTIME:
                raise ValueError(f"realtime priority of group {group!r}: {value} is not in 1..{MAX_REALTIME}")
        return realtime

    @field_validator("groups")
    @classmethod
    def _one_group_per_node(cls, groups: dict[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:
        owner: dict[str, str] = {}
        for group, nodes in groups.items():
            if not GROUP_NAME.match(group):
                raise ValueError(f"group name {group!r}: lower-case letters, digits and '_'")
            for node in nodes:
                if node in owner:
                    raise ValueError(f"node {node!r} is in two groups: {owner[node]!r} and {group!r}")
                owner[node] = group
        return groups


def group_of(groups: Mapping[str, tuple[str, ...]], nodes: list[str]) -> dict[str, list[str]]:
    """The groups that run ``nodes`` (in their order; empty groups left out), or a one-line
    error naming the first node that is in no group."""
    owner = {node: group for group, members in groups.items() for node in members}
    out: dict[str, list[str]] = {}
    for node in nodes:
        group = owner.get(node)
        if group is None:
            raise ConfigError(
                f"node {node!r} is in no process group; add it to processes.groups in the "
                f"profile (groups: {', '.join(groups)})"
            )
        out.setdefault(group, []).append(node)
    return out
