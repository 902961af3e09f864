"""Read the robot's geometry from its URDF (or a simple xacro), for the profile.

The seed keeps the lidar mount and the wheels in ``description/sage*.urdf.xacro``
(``base_link`` → ``lidar_link``, ``left_wheel``, ``right_wheel``). This reads those joints'
origins: the lidar pose relative to base_link and the wheel track (the lateral distance
between the two drive wheels). Plain xacro properties (``<xacro:property name value/>``
and ``${expr}`` with numbers, + - * / and ``pi``) are expanded; macros are not — expand
those with ROS's ``xacro`` tool first.
"""

from __future__ import annotations

import ast
import math
import operator
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sage_robot.core.errors import ConfigError

XACRO_NS = "http://www.ros.org/wiki/xacro"
_OPS: dict[type, Any] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
    ast.Pow: operator.pow,
}


def _eval(expr: str, props: dict[str, float]) -> float:
    """Evaluate a xacro arithmetic expression safely (numbers, properties, pi, + - * / **)."""

    def ev(node: ast.AST) -> float:
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return float(node.value)
        if isinstance(node, ast.Name):
            if node.id == "pi":
                return math.pi
            if node.id in props:
                return props[node.id]
            raise ConfigError(f"xacro: unknown property '{node.id}'")
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            return float(_OPS[type(node.op)](ev(node.left), ev(node.right)))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
            return float(_OPS[type(node.op)](ev(node.operand)))
        raise ConfigError(f"xacro: cannot evaluate '{expr}' (only numbers, properties and + - * / **)")

    return ev(ast.parse(expr, mode="eval"))


def _expand(text: str, props: dict[str, float]) -> str:
    return re.sub(r"\$\{([^}]*)\}", lambda m: repr(_eval(m.group(1), props)), text)


@dataclass(frozen=True)
class RobotGeometry:
    lidar_xyz: tuple[float, float, float]
    lidar_yaw: float
    track_width_m: float | None

    def profile_yaml(self) -> str:
        x, y, z = self.lidar_xyz
        lines = ["robot:"]
        if self.track_width_m is not None:
            lines.append(f"  track_width_m: {self.track_width_m:.4f}")
        lines.append(f"  lidar: {{x_m: {x:.4f}, y_m: {y:.4f}, z_m: {z:.4f}, yaw_rad: {self.lidar_yaw:.4f}}}")
        return "\n".join(lines) + "\n"


def _origin(joint: ET.Element, props: dict[str, float]) -> tuple[tuple[float, float, float], float]:
    origin = joint.find("origin")
    if origin is None:
        return (0.0, 0.0, 0.0), 0.0
    xyz = [
        _eval(v, props) if not _is_number(v) else float(v)
        for v in _expand(origin.get("xyz", "0 0 0"), props).split()
    ]
    rpy = [float(v) for v in _expand(origin.get("rpy", "0 0 0"), props).split()]
    return (xyz[0], xyz[1], xyz[2]), rpy[2]


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _chain_to(
    joints: dict[str, ET.Element], link: str, root: str, props: dict[str, float]
) -> tuple[tuple[float, float, float], float]:
    """Compose joint origins from ``root`` down to ``link`` (planar: yaw only)."""
    chain = []
    while link != root:
        joint = joints.get(link)
        if joint is None:
            raise ConfigError(f"URDF: no joint connects '{link}' to '{root}'")
        chain.append(joint)
        parent = joint.find("parent")
        link = parent.get("link", "") if parent is not None else ""
    x = y = z = yaw = 0.0
    for joint in reversed(chain):
        (jx, jy, jz), jyaw = _origin(joint, props)
        c, s = math.cos(yaw), math.sin(yaw)
        x, y, z, yaw = x + c * jx - s * jy, y + s * jx + c * jy, z + jz, yaw + jyaw
    return (x, y, z), yaw


def read_geometry(
    path: str | Path,
    lidar_link: str = "lidar_link",
    base_link: str = "base_link",
    wheels: tuple[str, str] = ("left_wheel", "right_wheel"),
) -> RobotGeometry:
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found") from None
    except ET.ParseError as exc:
        raise ConfigError(f"{p}: not valid XML: {exc}") from None
    props: dict[str, float] = {}
    for prop in root.iter(f"{{{XACRO_NS}}}property"):
        name, value = prop.get("name"), prop.get("value")
        if name and value is not None:
            try:
                props[name] = _eval(_expand(value, props).strip(), props)
            except (ConfigError, SyntaxError):
                continue  # non-numeric property (a string, a block): not geometry
    joints = {}
    for joint in root.iter("joint"):
        child = joint.find("child")
        if child is not None and child.get("link"):
            joints[child.get("link", "")] = joint
    try:
        lidar_xyz, lidar_yaw = _chain_to(joints, lidar_link, base_link, props)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    track = None
    if all(w in joints for w in wheels):
        (_, yl, _), _ = _chain_to(joints, wheels[0], base_link, props)
        (_, yr, _), _ = _chain_to(joints, wheels[1], base_link, props)
        track = abs(yl - yr)
    return RobotGeometry(lidar_xyz, lidar_yaw, track)
