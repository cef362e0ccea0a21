"""Whether the sensor stayed still between two scans, from the scans alone.

A robot with no odometry yet (just switched on, kidnapped, a hand-held sensor set down) can still
fuse the scans it sees while at rest: a non-repeating LiDAR fills in its field of view over time,
so a second of a resting Livox is several times denser than one frame. Fused at identity, they
are a sparse scan made dense, with no odometry to trust.

Whether the sensor was at rest is measured where it matters, in the scans: the newer is aligned to
the older by the estimator's point-to-plane refinement from identity, both at the registration's
voxel (planes: two samplings of the same surfaces hold still, where nearest points drift). It was still when
- nearly all of the newer scan's points (MIN_OVERLAP) lie on the older scan's surfaces: at rest
  both see the same scene, and an alignment that leaves much of it unpaired found a motion's
  local minimum, not rest;
- the surfaces they lie on fix all six degrees of freedom (estimate.pose_covariance): in a
  corridor a motion along it would not show, so it cannot be told from rest;
- the alignment moves the newer scan's points by less than STILL_VOXELS of a voxel (RMS): fused at
  identity, they are then off by less than the grid the registration works at blurs anyway.
A scan that moved, or a scene that changed under it, is not still.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from .cloud import clean_points
from .estimate import UNCONSTRAINED_VARIANCE, inliers_at, plane_refine, plane_thresholds, pose_covariance
from .features import surface_normals
from .geometry import moved
from .neighbour_grid import NeighbourGrid
from .sequence import ScanSequence
from .viewpoint import ORIGIN

STILL_VOXELS = 0.5      # the most a still scan may move, in voxels (RMS over its points)
MIN_OVERLAP = 0.8       # of the newer scan's points on the older one's surfaces: at rest both see
                        # the same surfaces, and what one lacks is its own sampling's gaps
PAIRING_VOXELS = 2.0    # a point pairs with a surface this near (voxels): a resting sensor's
                        # scans sample the same surfaces at different spots within a voxel or so
NORMAL_NEIGHBOURS = 30


@dataclass(frozen=True)
class Stillness:
    """How the newer of two scans lies against the older, and whether that is rest."""

    still: bool
    moved_m: float       # RMS motion of the newer scan's points that aligns it to the older
    overlap: float       # fraction of the newer scan's points on the older scan's surfaces
    constrained: bool    # the surfaces they lie on fix all six degrees of freedom
    reason: str          # why it is not still; empty when it is


def _down(points: np.ndarray, voxel: float, name: str) -> np.ndarray:
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(clean_points(points, name)))
    return np.asarray(cloud.voxel_down_sample(voxel).points, dtype=np.float64)


def was_still(older: np.ndarray, newer: np.ndarray, voxel: float, normal_radius: float) -> Stillness:
    """Whether the sensor was at rest from scan ``older`` to scan ``newer`` (each (N, 3) in its
    sensor's frame), judged at ``voxel``; ``normal_radius`` gives the older scan's surfaces."""
    target, source = _down(older, voxel, "older scan"), _down(newer, voxel, "newer scan")
    if len(target) < 7 or len(source) < 7:
        return Stillness(False, float("nan"), 0.0, False, "too few points to compare the scans")
    threshold, grid = PAIRING_VOXELS * voxel, NeighbourGrid(target)
    normals = surface_normals(target, normal_radius, NORMAL_NEIGHBOURS)
    aligned = plane_refine(np.eye(4), source, grid, normals, plane_thresholds(threshold, voxel), voxel)
    refined = inliers_at(aligned, source, grid, threshold)
    overlap = len(refined.source_index) / len(source)
    moved_m = moved(aligned, np.eye(4), source)
    covariance = pose_covariance(refined.transform, source[refined.source_index], target[refined.target_index],
                                 normals[refined.target_index], voxel)
    constrained = bool(np.linalg.eigvalsh(covariance).max() < UNCONSTRAINED_VARIANCE)
    if overlap < MIN_OVERLAP:
        reason = (f"only {100 * overlap:.0f} % of the newer scan lies on the older's surfaces: "
                  "it moved, or the scene did")
    elif not constrained:
        reason = "the surfaces leave a motion free (a corridor, a plane): rest cannot be told from sliding along them"
    elif moved_m >= STILL_VOXELS * voxel:
        reason = f"the sensor moved {moved_m:.3f} m between the scans (still: under {STILL_VOXELS * voxel:g} m)"
    else:
        reason = ""
    return Stillness(not reason, moved_m, overlap, constrained, reason)


def still_run(scans: list[np.ndarray], voxel: float, normal_radius: float) -> tuple[int, str]:
    """(how many of the newest ``scans`` (oldest first) were seen at rest with the newest, the
    newest counted; why the run stops there, empty when every scan is in it): each older scan is
    compared with the newest, newest first, until one is not still."""
    if len(scans) < 2:
        return len(scans), ""
    newest = scans[-1]
    for count, older in enumerate(reversed(scans[:-1]), start=1):
        verdict = was_still(older, newest, voxel, normal_radius)
        if not verdict.still:
            return count, verdict.reason
    return len(scans), ""


def at_rest(scans: list[np.ndarray], voxel: float, normal_radius: float,
            viewpoint=ORIGIN) -> tuple[ScanSequence | None, str]:
    """(the newest of ``scans`` (oldest first, each in its sensor's frame, ``viewpoint`` the sensor
    there) that were seen at rest with the newest, fused at identity; None when fewer than two
    were: register the newest alone), and why the run stopped where it did (empty: every scan)."""
    count, reason = still_run(scans, voxel, normal_radius)
    if count < 2:
        return None, reason
    return ScanSequence(list(scans[-count:]), [np.eye(4)] * count, viewpoint), reason
