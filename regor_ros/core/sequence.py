"""Scans accumulated along odometry: one local cloud, registered as the newest scan.

A single sparse scan (a narrow-field LiDAR's few thousand points) often carries too few correct
feature matches to be found in a map. The scans received just before it, moved into its frame by
odometry (accurate over a few metres), make a denser, wider cloud of the same place. Each scan
keeps its own viewpoint, so the free-space check sees through every one of them, and the pose
registered is the newest scan's.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .cloud import SeenCloud, check_viewpoint, clean_points
from .errors import RegistrationError
from .geometry import transform_points
from .viewpoint import ORIGIN

ROTATION_TOLERANCE = 1e-3  # |R^T R - I| beyond this is not a rotation (odometry quaternions are unit)


def checked_pose(pose, name: str) -> np.ndarray:
    """A 4x4 rigid transform, or RegistrationError naming what is wrong with it."""
    try:
        T = np.asarray(pose, dtype=np.float64)
    except (TypeError, ValueError):
        raise RegistrationError(f"{name}: not a numeric 4x4 matrix") from None
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise RegistrationError(f"{name}: expected a finite 4x4 transform, got shape {T.shape}")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) <= 0 \
            or np.abs(T[3] - [0, 0, 0, 1]).max() > ROTATION_TOLERANCE:
        raise RegistrationError(f"{name}: not a rigid transform (its rotation is not orthonormal)")
    return T


@dataclass
class ScanSequence:
    """Scans in their own sensor frames, oldest first, each with its odometry pose T_odom_scan.
    ``viewpoint`` is the sensor's position in a scan's frame (the origin for a scan published in
    its sensor frame)."""

    scans: Sequence[np.ndarray]
    poses: Sequence[np.ndarray]
    viewpoint: Sequence[float] = ORIGIN

    def __post_init__(self):
        if len(self.scans) == 0:
            raise RegistrationError("scan sequence: no scans")
        if len(self.scans) != len(self.poses):
            raise RegistrationError(f"scan sequence: {len(self.scans)} scans but {len(self.poses)} odometry poses")

    def fused(self) -> SeenCloud:
        """Every scan in the newest scan's frame, with its viewpoint there."""
        poses = [checked_pose(p, f"scan sequence: odometry pose {i}") for i, p in enumerate(self.poses)]
        viewpoint = check_viewpoint(self.viewpoint, "scan sequence")
        if viewpoint is None:
            raise RegistrationError("scan sequence: the scans' viewpoint must be known (they are sensor scans)")
        newest_from_odom = np.linalg.inv(poses[-1])
        parts: list[np.ndarray] = []
        viewpoints = []
        for i, (scan, pose) in enumerate(zip(self.scans, poses, strict=True)):
            T = newest_from_odom @ pose
            parts.append(transform_points(T, clean_points(scan, f"scan sequence: scan {i}")))
            viewpoints.append(transform_points(T, viewpoint[None])[0])
        return SeenCloud(parts, np.array(viewpoints))
