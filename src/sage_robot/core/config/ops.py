"""Operations: recording and the Foxglove live view."""

from __future__ import annotations

from pydantic import Field

from sage_robot.core.config.base import Section


class OpsSettings(Section):
    foxglove_host: str = Field(
        "127.0.0.1",
        description="Foxglove WebSocket server address. Loopback by default; any other address "
        "requires the Foxglove token (docs/security.md).",
    )
    foxglove_port: int = Field(8765, ge=0, lt=65536, description="Foxglove port (0 = any free port).")
    foxglove_origins: tuple[str, ...] = Field(
        ("https://app.foxglove.dev",),
        description="Browser origins allowed to open the Foxglove view besides loopback pages and "
        "web.allowed_origins.",
    )
    foxglove_map_period_s: float = Field(
        5.0, gt=0, description="Send /map to Foxglove at most this often (s)."
    )
    record_topics: tuple[str, ...] = Field(
        (
            "/scan",
            "/odom",
            "/map",
            "/cmd_vel",
            "/battery_state",
            "/plan",
            "/amcl_pose",
            "/sage/ui_state",
            "/imu/data",
            "/sage/events",
            "/sim/ground_truth",
        ),
        description="Topics `sage record` writes when none are named.",
    )
