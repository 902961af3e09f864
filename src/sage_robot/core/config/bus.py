"""The bus between processes: which transport, and how Zenoh peers find each other."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from sage_robot.core.config.base import Section

DEFAULT_ZENOH_PORT = 7450  # not 7447: Zenoh's router port (rmw_zenohd, the ROS 2 bridge's default)
ROBOT_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"  # one Zenoh key chunk, no wildcards


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
    config_file: str = Field(
        "",
        description="A Zenoh JSON5 configuration file applied first (router, TLS, user/password "
        "authentication for several machines: docs/operations.md). The keys above still apply.",
    )
    open_timeout_s: float = Field(
        2.0, gt=0, le=60, description="How long a tool waits for the robot to answer (s)."
    )


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
