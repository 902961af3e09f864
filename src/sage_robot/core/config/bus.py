"""The bus between processes: which transport, and how Zenoh peers find each other."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from sage_robot.core.config.base import Section

DEFAULT_ZENOH_PORT = 7450  # not 7447: Zenoh's router port (rmw_zenohd, the ROS 2 bridge's default)
ROBOT_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"  # one Zenoh key chunk, no wildcards
# Zenoh's thread pools (its ZENOH_RUNTIME, RON): receiving, sending, accepting and the network
# tasks all run on the one 'app' pool, so a message between processes wakes one thread, not three.
ONE_POOL_RUNTIME = "(rx: (handover: app), acc: (handover: app), tx: (handover: app), net: (handover: app))"
# Zenoh sends each message at once in a batch of its own (express), and a link queues 2 such
# batches by default: a sending thread that is not scheduled for 1 ms then drops the next one.
DEFAULT_TX_QUEUE = 16
MAX_TX_QUEUE = 16  # Zenoh's limit (transport/link/tx/queue/size/*)
# Streams that repeat themselves while the robot stands still (odometry, the map->odom
# correction, localization's verdict, the simulated speaker): a message equal to the last one
# sent to other processes but for its stamp goes again only after this long (s, of its stamps).
# Every change goes at once. Odometry keeps 4 Hz at rest for ROS 2 tools' TF lookups (it was
# 10 Hz: the navigator's process then woke 5 times a second more at rest; issue #24).
MAX_REPEAT_EVERY_S = 5.0  # a held-back stream still says it is alive this often (s)
DEFAULT_REPEAT_EVERY_S: dict[str, float] = {
    "/odom": 0.25,
    "/localization/map_odom": 0.2,
    "/localization/health": 0.5,
    "/sim/speaker": 0.5,
}


class ZenohSettings(Section):
    mode: Literal["peer", "client"] = Field(
        "peer",
        description="'peer' (processes of one machine talk directly) or 'client' (every "
        "process goes through a Zenoh router named in connect; several machines).",
    )
    listen: tuple[str, ...] = Field(
        (f"tcp/127.0.0.1:{DEFAULT_ZENOH_PORT}",),
        description="Endpoints the robot's process listens on. Loopback by default: nothing "
        "outside this machine can reach the bus. Tools connect here.",
    )
    connect: tuple[str, ...] = Field(
        (),
        description="Endpoints to connect to at start (another robot process's listen "
        "endpoint, or a router).",
    )
    multicast_scouting: bool = Field(
        False, description="Find peers by UDP multicast (off: endpoints are explicit)."
    )
    shared_memory: bool = Field(
        False,
        description="Zenoh's shared-memory transport. SAGE's messages are plain bytes, which never "
        "use it; on, every process runs its 20 Hz watchdog thread (at rest the robot's processes "
        "took ~13 % more CPU: docs/benchmarks.md, the robot at rest).",
    )
    tx_queue: int = Field(
        DEFAULT_TX_QUEUE,
        ge=1,
        le=MAX_TX_QUEUE,
        description="Messages (batches) each link may queue at the data priority, where every topic "
        "goes, before Zenoh drops one; a publisher waits at most 1 ms for room. Zenoh's default, 2, "
        "lost 1-4 of 50 paced /cmd_vel messages between two processes on a busy machine "
        "(docs/benchmarks.md); 16 lost none.",
    )
    config_file: str = Field(
        "",
        description="A Zenoh JSON5 configuration file applied first (router, TLS, user/password "
        "authentication for several machines: docs/operations.md). The keys above still apply.",
    )
    open_timeout_s: float = Field(
        2.0, gt=0, le=60, description="How long a tool waits for the robot to answer (s)."
    )
    repeat_every_s: dict[str, float] = Field(
        default_factory=lambda: dict(DEFAULT_REPEAT_EVERY_S),
        description="Topic -> s. A message on the topic equal to the last one sent to other "
        "processes except for its stamp is sent again only when its stamp is this much newer; "
        "every change is sent at once, and nothing changes inside a process. Only messages with a "
        "stamp are ever held back (a /cmd_vel never is). {} sends every message.",
    )
    runtime: str = Field(
        ONE_POOL_RUNTIME,
        description="Zenoh's thread pools, as its ZENOH_RUNTIME environment variable takes them "
        "(RON). The default runs them all on one pool: a message between processes wakes one "
        "thread, not three (docs/benchmarks.md, the robot at rest). '' keeps Zenoh's own pools; "
        "a ZENOH_RUNTIME set in the environment wins. Read once, by a process's first session.",
    )

    @field_validator("repeat_every_s")
    @classmethod
    def _repeat_periods(cls, periods: dict[str, float]) -> dict[str, float]:
        for topic, period in periods.items():
            if not topic.startswith("/") or not 0 < period <= MAX_REPEAT_EVERY_S:
                raise ValueError(
                    f"repeat_every_s[{topic!r}]: a topic name and 0 < s <= {MAX_REPEAT_EVERY_S:g}"
                )
        return periods


class BusSettings(Section):
    transport: Literal["local", "zenoh"] = Field(
        "local",
        description="'local': topics stay inside the process. 'zenoh': also published over "
        "Zenoh so `sage topic`, `sage status` and other processes can attach.",
    )
    robot_id: str = Field(
        "sage",
        pattern=ROBOT_ID_PATTERN,
        description="The robot's namespace in Zenoh key expressions: sage/<robot_id>/topic/...",
    )
    zenoh: ZenohSettings = Field(default_factory=ZenohSettings)
