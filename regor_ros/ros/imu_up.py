"""The source sensor's up direction from a sensor_msgs/Imu stream, for the gravity prior.

REP 145: an IMU's orientation is relative to a frame whose z axis points up, and its linear
acceleration includes gravity's reaction, +9.8 m/s^2 upwards at rest. So the up direction in the
IMU's frame is the reference z axis seen from the IMU when an orientation is reported, and the
direction of the mean acceleration otherwise (many LiDARs' built-in IMUs report no orientation).
The mean is taken over a window before the scan, so braking and bumps average out; a sustained
acceleration a tilts it by atan(a / g), which gravity.max_tilt must cover.
"""
from __future__ import annotations

from collections import deque

import numpy as np
from scipy.spatial.transform import Rotation

MAX_MESSAGES = 2000  # 2 s of a 1 kHz IMU; older ones are dropped


class ImuUp:
    """Recent IMU readings and the up direction they give in the source cloud's frame."""

    def __init__(self):
        self._readings: deque[tuple[float, np.ndarray | None, np.ndarray]] = deque(maxlen=MAX_MESSAGES)

    def add(self, stamp: float, orientation_xyzw: np.ndarray | None, acceleration: np.ndarray) -> None:
        """One message: its stamp, its orientation quaternion or None (not reported), and its
        linear acceleration. Kept as given: only the one before a scan is ever turned into up."""
        usable = orientation_xyzw is not None and np.isfinite(orientation_xyzw).all() and \
            np.linalg.norm(orientation_xyzw) > 0.5
        self._readings.append((stamp, orientation_xyzw if usable else None,
                               np.asarray(acceleration, dtype=np.float64)))

    def up_at(self, stamp: float, window: float, R_sensor_imu: np.ndarray) -> tuple[np.ndarray | None, str]:
        """(unit up in the source cloud's frame, or None; where it came from) for a scan at
        ``stamp``: the orientation of the last message up to it, else the mean acceleration of
        the messages in the ``window`` seconds before it; ``R_sensor_imu`` is the IMU's
        orientation in the source cloud's frame."""
        before = [r for r in list(self._readings) if stamp - window <= r[0] <= stamp]
        if not before:
            return None, f"no IMU message in the {window:g} s before the scan"
        if before[-1][1] is not None:
            up_in_imu = Rotation.from_quat(before[-1][1]).inv().apply([0.0, 0.0, 1.0])
            return R_sensor_imu @ up_in_imu, "IMU orientation"
        mean = np.mean([r[2] for r in before], axis=0)
        norm = np.linalg.norm(mean)
        if not np.isfinite(norm) or norm < 1e-6:
            return None, "the IMU's accelerations average to zero (no gravity in them?)"
        return R_sensor_imu @ (mean / norm), f"mean IMU acceleration of {len(before)} messages"
