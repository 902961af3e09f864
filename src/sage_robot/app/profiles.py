"""Launch profiles: which nodes a mode runs. Names resolve through :mod:`registry`.

Each entry is ``(node name, critical)``: a critical node's loss stops the robot.
Areas add their nodes here as they land.
"""

from __future__ import annotations

PROFILES: dict[str, list[tuple[str, bool]]] = {
    # The whole system on the simulated robot in the simulated building.
    "sim": [
        ("sim_world", True),
        ("mcu_sim", True),
        ("heartbeat", False),
        ("battery_watchdog", False),
        ("foxglove", False),
        ("serial_bridge", True),
        ("map_server", False),
        ("localization", False),
        ("navigator", True),
        ("web", True),
        ("kb", False),
        ("brain", False),
        ("tour", False),
        ("voice", False),
    ],
    # The real robot on a tour (the seed's start_robot.sh).
    "tour": [
        ("heartbeat", False),
        ("battery_watchdog", False),
        ("foxglove", False),
        ("lidar", False),
        ("camera", False),
        ("serial_bridge", True),
        ("map_server", False),
        ("localization", False),
        ("navigator", True),
        ("web", True),
        ("kb", False),
        ("brain", False),
        ("tour", False),
        ("voice", False),
    ],
    # The real robot building a map (the seed's slam_robot.sh).
    "slam": [("heartbeat", False), ("foxglove", False), ("lidar", False), ("camera", False), ("web", True),
             ("serial_bridge", True), ("slam", False)],
}

# SLAM in the simulator (`sage slam`): what mapping needs and nothing else (the seed's
# slam_robot.sh, simulated): the world and the firmware model, the serial bridge (/odom), the
# web server (teleop, the growing map, `sage slam save`), Foxglove, liveness and battery alerts
# for a long drive, and the SLAM node. No map server, localization or navigator (there is no
# map yet), no knowledge base, brain or voice (nobody gets a tour while the map is built).
PROFILES["sim_slam"] = [
    ("sim_world", True),
    ("mcu_sim", True),
    ("heartbeat", False),
    ("battery_watchdog", False),
    ("foxglove", False),
    ("serial_bridge", True),
    ("web", True),
    ("slam", False),
]
