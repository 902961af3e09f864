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
        ("voice", False),
    ],
    # The real robot building a map (the seed's slam_robot.sh).
    "slam": [("heartbeat", False), ("foxglove", False), ("lidar", False), ("camera", False), ("web", True),
             ("serial_bridge", True), ("slam", False)],
}

# SLAM in the simulator (`sage slam`): the "sim" profile as it stands when this module is
# imported, without localization, navigator and map server, plus the SLAM node.
PROFILES["sim_slam"] = [
    entry for entry in PROFILES["sim"] if entry[0] not in ("localization", "navigator", "map_server")
] + [("slam", False)]
