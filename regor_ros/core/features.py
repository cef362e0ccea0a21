"""Turn raw points into keypoints with FPFH descriptors, once per cloud.

A PreparedCloud holds everything registration needs from one cloud, so a static target (a map)
is prepared once and reused for every source registered against it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from .config import FeatureConfig

# Coordinates beyond this are treated as garbage (float32 overflow, uninitialised buffers).
MAX_ABS_COORDINATE = 1e6


class RegistrationError(ValueError):
    """The input cannot be registered; the message says why and what to change."""


@dataclass
class PreparedCloud:
    """Keypoints (every voxel-downsampled point), their unit FPFH features and a kd-tree."""

    points: np.ndarray    # (N, 3) float64, metres
    normals: np.ndarray   # (N, 3) unit normals (for the pose covariance)
    features: np.ndarray  # (N, 33) float32, L2-normalised
    tree: cKDTree
    config: FeatureConfig  # the settings it was prepared with
    input_size: int        # finite points in the raw cloud

    def __len__(self) -> int:
        return len(self.points)


def clean_points(xyz, name: str = "cloud") -> np.ndarray:
    """Validate a raw cloud and drop non-finite points; raise RegistrationError on bad input."""
    try:
        arr = np.asarray(xyz, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RegistrationError(f"{name}: not a numeric array ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise RegistrationError(f"{name}: expected an (N, 3) array of x, y, z, got shape {arr.shape}")
    if len(arr) == 0:
        raise RegistrationError(f"{name}: the cloud is empty")
    finite = np.isfinite(arr).all(axis=1)
    sane = finite & (np.abs(arr) < MAX_ABS_COORDINATE).all(axis=1)
    if not sane.any():
        if finite.any():
            raise RegistrationError(f"{name}: every point has a coordinate beyond "
                                    f"{MAX_ABS_COORDINATE:g} m; is the unit metres?")
        raise RegistrationError(f"{name}: every point is NaN or infinite")
    return arr[sane]


GROUND_MIN_POINTS = 100
GROUND_RANSAC_SEED = 0


def remove_largest_plane(pcd: o3d.geometry.PointCloud, distance: float) -> o3d.geometry.PointCloud:
    """Drop the points of the largest plane (the ground of a LiDAR scan). Its features are
    ambiguous, and the rings a spinning sensor draws on it match between any two scans at the
    same sensor-relative place, pulling the pose toward 'no motion'. Seeded for determinism."""
    o3d.utility.random.seed(GROUND_RANSAC_SEED)
    _, plane = pcd.segment_plane(distance_threshold=distance, ransac_n=3, num_iterations=1000)
    return pcd.select_by_index(plane, invert=True)


def prepare(xyz, config: FeatureConfig, name: str = "cloud") -> PreparedCloud:
    """Downsample, estimate normals, compute FPFH and L2-normalise the features."""
    points = clean_points(xyz, name)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    down = pcd.voxel_down_sample(config.voxel_size)
    if config.remove_ground and len(down.points) >= GROUND_MIN_POINTS:
        down = remove_largest_plane(down, config.voxel_size)
    n = len(down.points)
    if n < config.min_points:
        raise RegistrationError(
            f"{name}: {n} points after downsampling at voxel_size={config.voxel_size:g} m "
            f"(from {len(points)}), need at least {config.min_points}; lower features.voxel_size "
            "or send a denser cloud")
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(
        radius=config.normal_radius, max_nn=config.normal_max_nn))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=config.fpfh_radius, max_nn=config.fpfh_max_nn))
    features = np.asarray(fpfh.data, dtype=np.float32).T
    features /= np.linalg.norm(features, axis=1, keepdims=True) + 1e-6
    keypoints = np.asarray(down.points, dtype=np.float64)
    normals = np.asarray(down.normals, dtype=np.float64)
    return PreparedCloud(keypoints, normals, np.ascontiguousarray(features), cKDTree(keypoints),
                         config, len(points))
