"""Simulated time on the wire: what the simulator publishes on ``/clock`` (as ROS 2 does)."""

from __future__ import annotations

from sage_robot.core.msgs.base import message


@message("rosgraph_msgs/msg/Clock")
class SimTime:
    """The simulator's time (s since the simulation began); processes that follow it
    (``use_sim_time``) take their time from the last one received, and move it on at
    ``speed`` (the real-time factor the simulator is paced at; 0 when it is not) until the
    next one."""

    clock: float
    speed: float = 0.0
