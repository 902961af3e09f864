"""Messages of the SLAM node: progress while mapping and the save service."""

from __future__ import annotations

from sage_robot.core.msgs import Pose2D
from sage_robot.core.msgs.base import message


@message("foxglove/Json")
class SlamProgress:
    """Published after each processed scan: how mapping is going."""

    stamp: float  # s, node clock
    scans: int  # scans processed
    keyframes: int  # pose-graph nodes
    loop_closures: int  # loop-closure edges accepted
    match_score: float  # last scan-match score, 0..1 (0: dead-reckoned)
    pose: Pose2D  # current pose in the map frame
    optimizations: int = 0


@message()
class SaveMapRequest:
    """Save the map as ``name`` (letters, digits, '_', '-', '.') in ``directory`` (empty: the
    node's default output directory)."""

    name: str
    directory: str = ""


@message()
class SaveMapReply:
    yaml: str
    pgm: str
    graph: str
    trajectory: str
