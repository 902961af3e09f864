"""SLAM settings for a low-cost lidar with range noise (the seed robot's RPLIDAR A1M8: 1 %).

The engine's defaults (:class:`~sage_robot.nav.slam.engine.SlamConfig`) suit a survey-grade
scanner (the SICK of the CARMEN logs). With a noisy lidar, long corridors need the fixes of
issue #23 (``docs/slam.md``, "SLAM in simulation"): scan-to-submap edges, odometry
calibration, odometry edges that trust its travel once its scale is known (and, with the gyro,
its heading too, and the lidar's range to a wall straight ahead as a second ruler of the
odometry's scale), doubtful matches that turn far from the odometry left out, oriented and smoothed map
normals, local-map points two keyframes agree on, people's legs left out of matching,
pairings weighed by the range noise, and weighed the same where the scan pins the pose in
every direction. The robot's
``slam`` node (``slam.range_noise_fraction`` > 0) and ``sage bench slam --sim`` both use
:func:`noisy_lidar_config`, so the benchmark measures what the robot runs.
"""

from __future__ import annotations

import dataclasses

from sage_robot.nav.slam.engine import SlamConfig

SUBMAP_EDGE_STRIDES = (4, 8, 16, 24)  # scan-to-submap edges (see SlamConfig)
MAP_NORMAL_NEIGHBOURS = 32  # local-map normals for a lidar with 1 % range noise
MAP_MIN_SUPPORT = 2  # keyframes that must agree on a local-map point
SMALL_OBJECT_M = 0.25  # foreground objects this small (legs) are not matched
# A match at least this isotropic (x, y information: weakest / strongest direction) is refined
# again with every pairing weighing the same (MatchConfig.equal_weights_isotropy)
EQUAL_WEIGHTS_ISOTROPY = 0.25
# The odometry edge between keyframes the gyro turned, once calibrated: x, y noise of this base
# (m) + this fraction of the distance (the wheels' random noise is ~1 cm after 1 m)
GYRO_ODOM_SIGMA_XY_M = 0.005
GYRO_ODOM_SIGMA_XY_FRACTION = 0.03
# The wheels' odometry edges are stiff once the calibration's scale is known to this standard
# error (a fraction): on the corridor drive after about 170 m; at 0.5 % (after 30-40 m) a
# 40 m drive came out 0.6 % long (docs/slam.md, "The wheels alone"). Before, their sigma is the
# stiff one times the scale's error over this, at most the weak one.
WHEEL_TRAVEL_SCALE_ERROR = 0.002
# A doubtful match turned this far (rad) from the odometry's prediction is not believed: the
# odometry turns a few thousandths of a radian off in a scan (the wheels once calibrated, a gyro)
DOUBTFUL_TURN_GATE_RAD = 0.1


def noisy_lidar_config(base: SlamConfig, range_noise_fraction: float) -> SlamConfig:
    """``base`` with the settings for a lidar whose range noise is this fraction of the range
    (1 sigma); ``base`` itself when it is 0."""
    if range_noise_fraction <= 0:
        return base
    return dataclasses.replace(
        base,
        submap_edge_strides=SUBMAP_EDGE_STRIDES,
        calibrate_odometry=True,
        end_wall_ruler=True,
        gyro_odom_sigma_xy_m=GYRO_ODOM_SIGMA_XY_M,
        gyro_odom_sigma_xy_fraction=GYRO_ODOM_SIGMA_XY_FRACTION,
        wheel_travel_scale_error=WHEEL_TRAVEL_SCALE_ERROR,
        doubtful_turn_gate_rad=DOUBTFUL_TURN_GATE_RAD,
        oriented_normals=True,
        map_normal_neighbours=MAP_NORMAL_NEIGHBOURS,
        map_min_support=MAP_MIN_SUPPORT,
        drop_small_objects_m=SMALL_OBJECT_M,
        match=dataclasses.replace(
            base.match,
            range_noise_fraction=range_noise_fraction,
            equal_weights_isotropy=EQUAL_WEIGHTS_ISOTROPY,
        ),
    )
