"""Nodes by name. A profile lists names; each maps to ``module:Class`` imported on demand,
so a robot without the voice extra never imports speech models."""

from __future__ import annotations

import importlib

from sage_robot.core.errors import ConfigError
from sage_robot.core.node import Node

NODES: dict[str, str] = {
    "heartbeat": "sage_robot.app.builtin:HeartbeatNode",
    "map_server": "sage_robot.nav.map_server:MapServerNode",
    "localization": "sage_robot.nav.localization:LocalizationNode",
    "navigator": "sage_robot.nav.navigator:NavigatorNode",
    "sim_world": "sage_robot.sim.node:WorldNode",
    "kb": "sage_robot.kb.node:KbNode",
    "battery_watchdog": "sage_robot.app.battery_watchdog:BatteryWatchdogNode",
    "lidar": "sage_robot.hardware.rplidar.node:LidarNode",
    "camera": "sage_robot.hardware.camera:CameraNode",
    "recorder": "sage_robot.app.recording.nodes:RecorderNode",
    "replay": "sage_robot.app.recording.nodes:ReplayNode",
    "foxglove": "sage_robot.app.recording.nodes:FoxgloveNode",
    "mcu_sim": "sage_robot.sim.mcu_pty:McuSimNode",
    "serial_bridge": "sage_robot.hardware.mcu.bridge:SerialBridgeNode",
    "web": "sage_robot.web.node:WebNode",
    "brain": "sage_robot.brain.node:BrainNode",
    "tour": "sage_robot.brain.tour_runner:TourNode",
    "slam": "sage_robot.nav.slam.node:SlamNode",
    "voice": "sage_robot.voice.node:VoiceNode",
    "ros2_bridge": "sage_robot.app.ros2_bridge:Ros2BridgeNode",  # off by default: `sage sim --ros2`
}

# Which extra provides a node's module, for the message when its import fails.
EXTRAS_HINT = "pip install 'sage-robot[all]'"


def node_class(name: str) -> type[Node]:
    """The class registered under ``name``; a clear error for unknown or uninstalled ones."""
    target = NODES.get(name)
    if target is None:
        known = ", ".join(sorted(NODES))
        raise ConfigError(f"unknown node {name!r}; known nodes: {known}")
    module_name, _, cls_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(
            f"node {name!r} needs {exc.name or 'a package'} that is not installed; "
            f"install it with: {EXTRAS_HINT}"
        ) from None
    cls = getattr(module, cls_name)
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise TypeError(f"{target} is not a Node")
    return cls
