import pytest

from sage_robot.app.urdf import read_geometry
from sage_robot.core.config import parse_profile
from sage_robot.core.errors import ConfigError

SEED_LIKE = """<?xml version="1.0"?>
<robot name="sage" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:property name="track" value="0.381"/>
  <xacro:property name="lidar_x" value="0.1466"/>
  <xacro:property name="lidar_h" value="${0.5 + 0.027}"/>
  <link name="base_link"/>
  <link name="chassis"/>
  <link name="lidar_link"/>
  <link name="left_wheel"/>
  <link name="right_wheel"/>
  <joint name="chassis_joint" type="fixed">
    <parent link="base_link"/><child link="chassis"/><origin xyz="0 0 0.1" rpy="0 0 0"/>
  </joint>
  <joint name="lidar_joint" type="fixed">
    <parent link="chassis"/><child link="lidar_link"/>
    <origin xyz="${lidar_x} 0 ${lidar_h - 0.1}" rpy="0 0 ${pi}"/>
  </joint>
  <joint name="left_wheel_joint" type="continuous">
    <parent link="base_link"/><child link="left_wheel"/><origin xyz="0 ${track/2} 0" rpy="${-pi/2} 0 0"/>
  </joint>
  <joint name="right_wheel_joint" type="continuous">
    <parent link="base_link"/><child link="right_wheel"/><origin xyz="0 ${-track/2} 0" rpy="${pi/2} 0 0"/>
  </joint>
</robot>
"""


def test_seed_like_xacro_gives_lidar_pose_and_track(tmp_path):
    f = tmp_path / "sage.urdf.xacro"
    f.write_text(SEED_LIKE)
    geo = read_geometry(f)
    assert geo.lidar_xyz == pytest.approx((0.1466, 0.0, 0.527))
    assert geo.lidar_yaw == pytest.approx(3.14159265, abs=1e-6)
    assert geo.track_width_m == pytest.approx(0.381)
    settings = parse_profile(geo.profile_yaml(), "from-urdf")  # the snippet is a valid profile
    assert settings.robot.lidar.z_m == pytest.approx(0.527, abs=1e-4)


def test_missing_lidar_joint_is_named(tmp_path):
    f = tmp_path / "r.urdf"
    f.write_text('<robot name="r"><link name="base_link"/></robot>')
    with pytest.raises(ConfigError, match="no joint connects 'lidar_link'"):
        read_geometry(f)
