"""An EKF fusing wheel odometry with the IMU's yaw rate (the seed's robot_localization role).

State ``[x, y, theta, v, w]`` in the odom frame (m, rad, m/s, rad/s), constant-velocity
process model. Measurements: the wheel odometry's body twist (v, w) and the gyro's yaw
rate w. Dead wheels measure ``v`` well but slip and tilt corrupt their ``w``; the gyro
measures ``w`` well, so the fused heading drifts less than the wheels' own.
"""

from __future__ import annotations

import math

import numpy as np

from sage_robot.core.geometry import wrap_angle

Q_DIAG = (1e-4, 1e-4, 1e-4, 0.5, 0.5)  # process noise density per second (x, y, theta, v, w)
ODOM_V_VAR = 0.01**2  # (m/s)^2
ODOM_W_VAR = 0.05**2  # (rad/s)^2: wheel yaw rate is the weak part
IMU_W_VAR = 0.01**2  # (rad/s)^2


class YawRateEkf:
    """Predict with :meth:`predict`, correct with :meth:`odom` and :meth:`imu`."""

    def __init__(self) -> None:
        self.x = np.zeros(5)
        self.P = np.eye(5) * 1e-3
        self.t: float | None = None

    def reset(self, x: float, y: float, theta: float) -> None:
        self.x = np.array([x, y, theta, 0.0, 0.0])
        self.P = np.eye(5) * 1e-3

    def predict(self, t: float) -> None:
        if self.t is None:
            self.t = t
            return
        dt = t - self.t
        if dt <= 0:
            return
        self.t = t
        x, y, th, v, w = self.x
        self.x = np.array([x + v * math.cos(th) * dt, y + v * math.sin(th) * dt,
                           wrap_angle(th + w * dt), v, w])
        F = np.eye(5)
        F[0, 2], F[0, 3] = -v * math.sin(th) * dt, math.cos(th) * dt
        F[1, 2], F[1, 3] = v * math.cos(th) * dt, math.sin(th) * dt
        F[2, 4] = dt
        self.P = F @ self.P @ F.T + np.diag(Q_DIAG) * dt

    def _correct(self, H: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        y = z - H @ self.x
        S = H @ self.P @ H.T + R
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ y
        self.x[2] = wrap_angle(self.x[2])
        self.P = (np.eye(5) - K @ H) @ self.P

    def odom(self, t: float, v: float, w: float) -> None:
        self.predict(t)
        H = np.zeros((2, 5))
        H[0, 3] = H[1, 4] = 1.0
        self._correct(H, np.array([v, w]), np.diag([ODOM_V_VAR, ODOM_W_VAR]))

    def imu(self, t: float, yaw_rate: float) -> None:
        self.predict(t)
        H = np.zeros((1, 5))
        H[0, 4] = 1.0
        self._correct(H, np.array([yaw_rate]), np.array([[IMU_W_VAR]]))

    @property
    def pose(self) -> tuple[float, float, float]:
        return (float(self.x[0]), float(self.x[1]), float(self.x[2]))
