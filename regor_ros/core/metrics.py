"""Evaluation metrics of the paper (SPEC section 4): RE, TE, success, IP, IN, INR, FMR."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# (max rotation error in degrees, max translation error in metres) counted as a success
SUCCESS_THRESHOLDS = {"indoor": (15.0, 0.30), "object": (15.0, 0.30), "outdoor": (5.0, 0.60)}
# (rotation error in degrees, translation error in metres) beyond which a wrong pose is gross: of
# no use to a robot at all, where one within them is a near miss (of a ground truth itself loose by
# a few degrees, as 3DMatch's is) that a local refinement brings in
GROSS_THRESHOLDS = {"indoor": (20.0, 0.60), "object": (20.0, 0.60 * 0.06), "outdoor": (20.0, 0.60)}
# ground-truth residual below which a correspondence is correct [m]
INLIER_THRESHOLDS = {"indoor": 0.10, "object": 0.10 * 0.06, "outdoor": 0.60}


def random_rigid_motion(seed, max_translation: float = 1.0) -> np.ndarray:
    """A uniformly random rotation and a translation within +-max_translation per axis, drawn
    from ``seed`` (an int or a sequence of ints): moving a source by it makes a test global."""
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-max_translation, max_translation, 3)
    return T


def rotation_error_deg(T_est: np.ndarray, T_gt: np.ndarray) -> float:
    """The angle of the rotation between two poses [deg]."""
    cos = (np.trace(T_est[:3, :3].T @ T_gt[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def translation_error(T_est: np.ndarray, T_gt: np.ndarray) -> float:
    """The distance between two poses' translations [m]."""
    return float(np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3]))


def is_success(T_est: np.ndarray, T_gt: np.ndarray, kind: str) -> bool:
    """Within the benchmark's rotation and translation thresholds for this kind of data."""
    max_re, max_te = SUCCESS_THRESHOLDS[kind]
    return rotation_error_deg(T_est, T_gt) < max_re and translation_error(T_est, T_gt) < max_te


def is_gross(rotation_error: float, translation_error_m: float, kind: str) -> bool:
    """A wrong pose beyond this kind's GROSS_THRESHOLDS; one with no truth to measure it against
    (NaN: a cross-place pose) is."""
    max_re, max_te = GROSS_THRESHOLDS[kind]
    return not (rotation_error <= max_re and translation_error_m <= max_te)


def error_sigmas(T_est: np.ndarray, T_gt: np.ndarray, covariance: np.ndarray) -> float:
    """How many standard deviations of ``covariance`` (6x6 over x, y, z and a small turn about the
    pose's position, in the target frame's axes, as register() reports it) the error is: the
    Mahalanobis distance of (position error, rotation vector of R_est R_gt^T). A covariance that
    states the real uncertainty keeps 99 % of errors within ERROR_SIGMAS_99."""
    error = np.r_[T_est[:3, 3] - T_gt[:3, 3], Rotation.from_matrix(T_est[:3, :3] @ T_gt[:3, :3].T).as_rotvec()]
    return float(np.sqrt(error @ np.linalg.solve(covariance, error)))


ERROR_SIGMAS_99 = 4.1   # square root of the chi-square 99 % quantile with 6 degrees of freedom (16.81)


def correct_mask(source: np.ndarray, target: np.ndarray, T_gt: np.ndarray, threshold: float) -> np.ndarray:
    """Correspondences whose source point lands within ``threshold`` of its target under the truth."""
    moved = source @ T_gt[:3, :3].T + T_gt[:3, 3]
    return np.linalg.norm(moved - target, axis=1) < threshold
