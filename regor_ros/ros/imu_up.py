"""The source sensor's up direction from a sensor_msgs/Imu stream, for the gravity prior.

REP 145: an IMU's orientation is relative to a frame whose z axis points up, and its linear
acceleration includes gravity's reaction, +9.8 m/s^2 upwards at rest. So the up direction in the
IMU's frame is the reference z axis seen from the IMU when an orientation is reported, and the
direction of the mean acceleration otherwise (many LiDARs' built-in IMUs report no orientation).
The mean is taken over a window before the scan, so braking and bumps average out; a sustained
acceleration a tilts it by atan(a / g), which gravity.max_tilt must cover. A sensor that turns
during the window (carried, or a robot cornering) sees gravity from a turning frame: each reading
is first turned into the frame of the last one by the gyro, its angular velocity integrated over
the window (accurate over a second), so the mean is gravity as the sensor sees it at the scan, not
smeared over where it pointed before.
"""
from __future__ import annotations

from collections import deque

import numpy as np
from scipy.spatial.transform import Rotation

MAX_MESSAGES = 2000  # 2 s of a 1 kHz IMU; older ones are dropped


class ImuUp:
    """Recent IMU readings and the up direction they give in the source cloud's frame."""

    def __init__(self):
        self._readings: deque[tuple[float, np.ndarray | None, np.ndarray, np.ndarray]] = deque(maxlen=MAX_MESSAGES)

    def add(self, stamp: float, orientation_xyzw: np.ndarray | None, acceleration: np.ndarray,
            angular_velocity: np.ndarray | None = None) -> None:
        """One message: its stamp, its orientation quaternion or None (not reported), its linear
        acceleration and its angular velocity [rad/s] (None: not reported). Kept as given: only
        the ones before a scan are ever turned into up."""
        usable = orientation_xyzw is not None and np.isfinite(orientation_xyzw).all() and \
            np.linalg.norm(orientation_xyzw) > 0.5
        gyro = np.zeros(3) if angular_velocity is None else np.asarray(angular_velocity, dtype=np.float64)
        self._readings.append((stamp, orientation_xyzw if usable else None,
                               np.asarray(acceleration, dtype=np.float64),
                               gyro if np.isfinite(gyro).all() else np.zeros(3)))

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
        mean = np.mean(in_last_frame(np.array([r[0] for r in before]), np.array([r[2] for r in before]),
                                     np.array([r[3] for r in before])), axis=0)
        norm = np.linalg.norm(mean)
        if not np.isfinite(norm) or norm < 1e-6:
            return None, "the IMU's accelerations average to zero (no gravity in them?)"
        return R_sensor_imu @ (mean / norm), f"mean IMU acceleration of {len(before)} messages"


def in_last_frame(stamps: np.ndarray, vectors: np.ndarray, gyro: np.ndarray) -> np.ndarray:
    """Each reading's vector (in the IMU's frame when it was read) in the IMU's frame at the last
    reading: the body turns by each reading's angular velocity until the next one, and the turns
    are chained (no gyro: the vectors as they are)."""
    if not gyro.any():
        return vectors
    steps = Rotation.from_rotvec(gyro[:-1] * np.diff(stamps)[:, None])   # frame i+1 seen from frame i
    to_first = [Rotation.identity()]
    for step in steps:
        to_first.append(to_first[-1] * step)
    frames = Rotation.concatenate(to_first)                             # frame i seen from the first
    return (frames[-1].inv() * frames).apply(vectors)
