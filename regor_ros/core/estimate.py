"""Pose estimation: weighted Kabsch, the refinement loops, and the pose covariance."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import kernels
from .geometry import to_matrix, transform_points
from .metrics import rotation_error_deg, translation_error
from .neighbour_grid import NeighbourGrid


def agreeing(T: np.ndarray, source: np.ndarray, target: np.ndarray, threshold: float) -> np.ndarray:
    """Mask of the correspondences (source[i], target[i]) that T brings within ``threshold``."""
    return np.linalg.norm(transform_points(T, source) - target, axis=1) < threshold


Clamp = Callable[[np.ndarray], np.ndarray] | None  # brings (..., 3, 3) rotations inside a prior


def weighted_kabsch(source: np.ndarray, target: np.ndarray,
                    weights: np.ndarray | None = None, clamp: Clamp = None) -> np.ndarray:
    """Least-squares rigid transform(s) mapping source onto target.

    Works on (n, 3) or batched (b, n, 3) arrays; returns (4, 4) or (b, 4, 4). Reflections are
    excluded with the determinant correction. ``clamp`` (a gravity prior's) moves the rotation
    inside the prior before the translation is fitted to it.
    """
    if weights is None:
        weights = np.ones(source.shape[:-1])
    w = weights[..., None]
    wsum = w.sum(axis=-2, keepdims=True) + 1e-6
    src_c = (w * source).sum(axis=-2, keepdims=True) / wsum
    tgt_c = (w * target).sum(axis=-2, keepdims=True) / wsum
    H = np.swapaxes(w * (source - src_c), -1, -2) @ (target - tgt_c)
    return kabsch_from_moments(src_c[..., 0, :], tgt_c[..., 0, :], H, clamp)


def kabsch_from_moments(source_centroid: np.ndarray, target_centroid: np.ndarray, cross_covariance: np.ndarray,
                        clamp: Clamp = None) -> np.ndarray:
    """The rigid transform(s) of weighted_kabsch from the weighted centroids (..., 3) and the
    cross-covariance about them (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(cross_covariance)
    V = np.swapaxes(Vt, -1, -2)
    d = np.where(np.linalg.det(V @ np.swapaxes(U, -1, -2)) < 0, -1.0, 1.0)
    D = np.zeros(cross_covariance.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = V @ D @ np.swapaxes(U, -1, -2)
    if clamp is not None:
        R = clamp(R)
    t = target_centroid - (R @ source_centroid[..., None])[..., 0]
    return to_matrix(R, t)


def poses_close(A: np.ndarray, B: np.ndarray, angle_deg: float, translation: float) -> bool:
    """True when two transforms differ by less than ``angle_deg`` and ``translation``."""
    return rotation_error_deg(A, B) < angle_deg and translation_error(A, B) < translation


def post_refine(T: np.ndarray, source: np.ndarray, target: np.ndarray, threshold: float,
                iterations: int, clamp: Clamp = None) -> np.ndarray:
    """SC2-PCR's post-refinement on fixed correspondences: reweighted Kabsch on the inliers of
    the current pose until the inlier count stops changing."""
    return post_refine_all(T[None], source, target, threshold, iterations, clamp)[0]


def post_refine_all(starts: np.ndarray, source: np.ndarray, target: np.ndarray, threshold: float,
                    iterations: int, clamp: Clamp = None) -> np.ndarray:
    """post_refine of each of ``starts`` (b, 4, 4), stepped together (the initial stage refines
    every hypothesis it compares once): (b, 4, 4)."""
    source, target = (np.ascontiguousarray(x, dtype=np.float64) for x in (source, target))

    def moments(poses: np.ndarray) -> list:
        distance, *rest = kernels.fixed_pairs_moments(np.ascontiguousarray(poses[:, :3, :3]),
                                                      np.ascontiguousarray(poses[:, :3, 3]), source, target,
                                                      float(threshold))
        return [distance, None, *rest]

    return _reweighted(starts, moments, iterations, clamp)[0]


@dataclass
class PointRefinement:
    """A refined pose with its inlier keypoint pairs and their residuals."""

    transform: np.ndarray
    source_index: np.ndarray   # final inlier pairs (source keypoint, nearest target keypoint)
    target_index: np.ndarray
    distances: np.ndarray      # their residuals under the pose they were found with


def point_refine(T: np.ndarray, source: np.ndarray, target: NeighbourGrid, threshold: float,
                 iterations: int, clamp: Clamp = None) -> PointRefinement:
    """The estimator's point-level refinement: every source keypoint against its nearest target
    keypoint, Cauchy-weighted Kabsch on the pairs within ``threshold``, until the count settles."""
    return point_refine_all(T[None], source, target, threshold, iterations, clamp)[0]


def point_refine_all(starts: np.ndarray, source: np.ndarray, target: NeighbourGrid, threshold: float,
                     iterations: int, clamp: Clamp = None) -> list[PointRefinement]:
    """point_refine of each of ``starts`` (b, 4, 4), the poses still moving stepped together (one
    compiled pass per step for all of them: a gate's rivals are up to nine short refinements)."""
    poses, (distance, nearest, *_) = _reweighted(
        starts, lambda poses: list(target.pair_moments(poses, source, threshold)), iterations, clamp)
    refined = []
    for T, d, j in zip(poses, distance, nearest, strict=True):
        index = np.flatnonzero(d < threshold)
        refined.append(PointRefinement(T, index, j[index], d[index]))
    return refined


def _reweighted(starts: np.ndarray, moments_of: Callable[[np.ndarray], list], iterations: int,
                clamp: Clamp) -> tuple[np.ndarray, list]:
    """Cauchy-reweighted Kabsch steps of each of ``starts`` until its pair count stops changing
    or falls under three, the poses still moving stepped together. ``moments_of(poses)`` gives
    the pairs' [distance, nearest, count, source centroid, target centroid, cross-covariance]
    (PairMoments' fields) under each pose. (the poses, their last moments)."""
    poses = np.array(starts, dtype=np.float64).reshape(-1, 4, 4)
    moments = moments_of(poses)
    count = moments[2]
    previous = np.full(len(poses), -1)
    moving = np.ones(len(poses), dtype=bool)
    for _ in range(iterations):
        moving &= (count != previous) & (count >= 3)
        if not moving.any():
            break
        step = np.flatnonzero(moving)
        previous[step] = count[step]
        source_centroid, target_centroid, cross_covariance = (m[step] for m in moments[3:])
        poses[step] = kabsch_from_moments(source_centroid, target_centroid, cross_covariance, clamp)
        for m, new in zip(moments, moments_of(poses[step]), strict=True):
            if m is not None:
                m[step] = new
    return poses, moments


# a point-to-plane step moves along a direction only as far as the surfaces fix it: damping of
# this fraction of the best-fixed direction's curvature keeps free directions (a corridor's axis)
# where the point-level refinement left them
PLANE_DAMPING = 1e-3
# a step that moves the keypoints by less than this fraction of a voxel's sigma ends a threshold's
# iterations: the steps shrink geometrically, so what the rest would add stays well inside the
# resolution a right pose is known at (resolution_uncertainty)
PLANE_STEP_SETTLED = 0.1
PLANE_ITERATIONS = 5  # per threshold, at most: Gauss-Newton on planes settles in a few steps


def plane_thresholds(inlier_threshold: float, voxel_size: float) -> list:
    """The fine refinement's schedule: tau_e halved down to the keypoint spacing, below which a
    nearest neighbour is no longer the same surface element."""
    thresholds = [inlier_threshold]
    while thresholds[-1] / 2 >= voxel_size:
        thresholds.append(thresholds[-1] / 2)
    return thresholds


def _rotation(w: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation by the vector ``w`` (axis times angle in radians)."""
    angle = np.linalg.norm(w)
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if angle < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(angle) / angle * K + (1 - np.cos(angle)) / angle ** 2 * K @ K


def plane_refine(T: np.ndarray, source: np.ndarray, target: NeighbourGrid, target_normals: np.ndarray,
                 thresholds, voxel_size: float, clamp: Clamp = None) -> np.ndarray:
    """Point-to-plane refinement of a pose the point-level refinement found: Cauchy-weighted
    Gauss-Newton on each keypoint's distance to its nearest target keypoint's plane, the
    threshold annealed (``plane_thresholds``). The point-level refinement pairs keypoints up to
    tau_e apart (1.2 m outdoors), so a sparse scan's pose stays about half a voxel off; planes
    slide into place where points would have to coincide. A threshold's iterations end when a
    step moves the keypoints (its turn times their radius of gyration, plus its shift) by less
    than PLANE_STEP_SETTLED of a voxel's sigma: steps below the resolution only move the pose
    within what the voxel grid can tell apart."""
    normals = np.ascontiguousarray(target_normals, dtype=np.float64)
    lever = _gyration(source - source.mean(axis=0), voxel_size)
    settled_move = PLANE_STEP_SETTLED * _voxel_sigma(voxel_size)
    for threshold in thresholds:
        for _ in range(PLANE_ITERATIONS):
            moved = transform_points(T, source)
            distances, nearest = target.nearest_within(moved, threshold)
            # rotating about the paired points' centre
            pairs, centre, H, gradient = kernels.plane_step_system(moved, distances, nearest, target.points,
                                                                    normals, float(threshold))
            if pairs < 6:
                break
            H += PLANE_DAMPING * np.linalg.eigvalsh(H)[-1] * np.eye(6)
            step = -np.linalg.solve(H, gradient)
            rotation = _rotation(step[:3])
            if clamp is not None:
                rotation = clamp(rotation @ T[:3, :3]) @ T[:3, :3].T
            T = to_matrix(rotation, centre + step[3:] - rotation @ centre) @ T
            if np.linalg.norm(step[:3]) * lever + np.linalg.norm(step[3:]) < settled_move:
                break
    return T


def plane_refined(refined: PointRefinement, source: np.ndarray, target: NeighbourGrid, target_normals: np.ndarray,
                  inlier_threshold: float, voxel_size: float, clamp: Clamp = None) -> PointRefinement:
    """The point-to-plane refinement of a point-level ``refined`` pose, and its inliers within
    ``inlier_threshold`` (tau_e). It is kept when it puts at least as many source keypoints within
    one voxel of the target: the judge is the data at the keypoints' resolution, so a near miss a
    few degrees off is brought in, and a slide along a corridor or onto a repeated facade that fits
    worse is not taken."""
    fine = plane_refine(refined.transform, source, target, target_normals,
                        plane_thresholds(inlier_threshold, voxel_size), voxel_size, clamp)
    candidate = inliers_at(fine, source, target, inlier_threshold)
    # keypoints within a voxel of the target, from the residuals found within tau_e
    return candidate if (candidate.distances < voxel_size).sum() >= (refined.distances < voxel_size).sum() else refined


def settled(refined: PointRefinement, one_round: Callable[[np.ndarray], PointRefinement], source: np.ndarray,
            voxel_size: float, rounds: int) -> PointRefinement:
    """``refined``, refined again (``one_round``: the point level, then planes) until a round moves
    it by less than a right pose is known at this resolution (resolution_uncertainty), at most
    ``rounds`` times (estimation.settle_rounds). The point-level refinement stops when its inlier
    count stops changing; where tau_e spans several keypoint spacings, a scan whose keypoints
    nearly all lie within it keeps that count while the pose still moves, and a pose stopped part
    way down its basin, degrees from where the data put it, was published. A round is taken only
    when it puts at least as many keypoints within a voxel of the target (as plane_refined judges
    a step). A pose that has settled is returned as it was."""
    for _ in range(rounds):
        again = one_round(refined.transform)
        known_m, known_rad = resolution_uncertainty(refined.transform, source[refined.source_index], voxel_size)
        if (translation_error(again.transform, refined.transform) <= known_m
                and np.radians(rotation_error_deg(again.transform, refined.transform)) <= known_rad):
            return refined
        if (again.distances < voxel_size).sum() < (refined.distances < voxel_size).sum():
            return refined
        refined = again
    return refined


def inliers_at(T: np.ndarray, source: np.ndarray, target: NeighbourGrid, threshold: float) -> PointRefinement:
    """The keypoints ``T`` brings within ``threshold`` of a target keypoint: the final inliers."""
    distances, nearest = target.nearest_within(transform_points(T, source), threshold)
    index = np.flatnonzero(distances < threshold)
    return PointRefinement(T, index, nearest[index], distances[index])


UNCONSTRAINED_VARIANCE = 1e6  # covariance diagonal reported for degrees of freedom nothing fixes


def pose_covariance(T: np.ndarray, source: np.ndarray, target: np.ndarray,
                    target_normals: np.ndarray, voxel_size: float) -> np.ndarray:
    """6x6 covariance of (x, y, z, roll, pitch, yaw) from the point-to-plane residuals of the
    inlier pairs: sigma^2 (J^T J)^-1 for a small motion of the pose in the target frame's axes
    (translation first, as ROS orders it), rotating about the pose's own position: the position's
    uncertainty is the source origin's, not inflated by its distance from the target's origin
    (which, hundreds of metres out in a map, also made the system numerically singular).
    Point-to-plane exposes what the surfaces leave free (sliding along a plane or a corridor);
    such degrees of freedom get UNCONSTRAINED_VARIANCE.

    The residual term alone claims millimetres from thousands of keypoints, as if their errors
    were independent; they are not (every keypoint is a voxel's centroid, and neighbours share
    the map's blur), and on the real scan-to-map queries the errors were 10-40 times larger. So
    the resolution the registration works at is added (resolution_covariance)."""
    moved = transform_points(T, source)
    n = len(moved)
    if n < 7:
        return np.eye(6) * UNCONSTRAINED_VARIANCE
    arm = moved - T[:3, 3]
    residual = ((moved - target) * target_normals).sum(axis=1)
    J = np.hstack([target_normals, np.cross(arm, target_normals)])   # (n, 6)
    JtJ = J.T @ J
    eigenvalues, eigenvectors = np.linalg.eigh(JtJ)
    sigma2 = max(float(residual @ residual) / (n - 6), 1e-12)
    constrained = eigenvalues > 1e-9 * max(eigenvalues[-1], 1e-12)
    inverse = np.where(constrained, 1.0 / np.where(constrained, eigenvalues, 1.0), 0.0)
    covariance = (eigenvectors * (sigma2 * inverse)) @ eigenvectors.T
    if not constrained.all():
        covariance += UNCONSTRAINED_VARIANCE * (eigenvectors[:, ~constrained] @ eigenvectors[:, ~constrained].T)
    return covariance + resolution_covariance(JtJ, _gyration(arm, voxel_size), voxel_size)


def _voxel_sigma(voxel_size: float) -> float:
    """The standard deviation of a position known only to within a voxel (uniform across it)."""
    return voxel_size / np.sqrt(12.0)


def _gyration(arm: np.ndarray, voxel_size: float) -> float:
    """Radius of gyration of points about the pose's position (``arm``: their offsets), never under a voxel."""
    return max(float(np.sqrt(np.mean(np.sum(arm ** 2, axis=1)))), voxel_size)


def resolution_uncertainty(T: np.ndarray, source: np.ndarray, voxel_size: float):
    """(translation [m], turn [rad]) standard deviations a *right* pose has at this voxel size,
    with ``source`` (its inlier keypoints) as the lever: a voxel's sigma, and the turn that moves
    their radius of gyration by as much. The free-space check allows for this much; not for the
    residual term (a wrong pose's large residuals would buy it a wider margin) nor for weakly
    constrained directions (free space is what can catch an error along them)."""
    sigma = _voxel_sigma(voxel_size)
    if len(source) == 0:
        return sigma, 0.0
    return sigma, sigma / _gyration(transform_points(T, source) - T[:3, 3], voxel_size)


def resolution_covariance(JtJ: np.ndarray, gyration: float, voxel_size: float) -> np.ndarray:
    """The pose's uncertainty from the voxel grid the registration works at, shaped by the
    surfaces. Along the direction the inliers' normals constrain best the position is known within
    one voxel (sigma = voxel / sqrt(12)), and a turn within the one that moves the inliers' radius
    of gyration by as much. A keypoint pins the pose along its normal only, so a direction that
    the normals constrain k times less (a corridor's length, a road's heading, a narrow field of
    view down a street) is known sqrt(k) times less well: an error the grid's bias makes there is
    not corrected by anything. Never finer than the grid in any direction."""
    scale = np.r_[np.ones(3), np.full(3, 1.0 / gyration)]   # turns in units of the gyration
    eigenvalues, eigenvectors = np.linalg.eigh(JtJ * np.outer(scale, scale))
    weakness = eigenvalues[-1] / np.maximum(eigenvalues, eigenvalues[-1] / UNCONSTRAINED_VARIANCE)
    shape = (eigenvectors * weakness) @ eigenvectors.T
    return voxel_size ** 2 / 12.0 * shape * np.outer(scale, scale)
