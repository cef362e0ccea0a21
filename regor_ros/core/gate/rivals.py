"""The symmetric rivals of a pose: the pose turned by 180 degrees about each symmetry axis of
its overlap, refined like the pose. A box-like room, a corridor or a road turned around passes
every other check; when a rival explains the clouds about as well (gate/judge.py's ambiguity),
neither pose can be trusted."""
from __future__ import annotations

import numpy as np

from ..cloud import PreparedCloud
from ..config import RegorConfig
from ..estimate import agreeing, point_refine
from ..geometry import evenly_spaced, to_matrix
from ..gravity import GravityPrior
from ..metrics import rotation_error_deg
from .figures import RivalFigures
from .visibility import visibility_figures

RIVAL_POINTS = 1000   # evenly spaced source keypoints on which the pose and its rivals are compared
RIVAL_ITERATIONS = 10


def half_turns(points: np.ndarray) -> np.ndarray:
    """(3, 4, 4): turns by 180 degrees about each principal axis of ``points``, through their
    centroid: the symmetries of a box-like room, a corridor or a road."""
    centre = points.mean(axis=0)
    axes = np.linalg.svd(points - centre, full_matrices=False)[2]
    rotations = 2.0 * axes[:, :, None] * axes[:, None, :] - np.eye(3)
    return to_matrix(rotations, centre - rotations @ centre)


def symmetric_rivals(T: np.ndarray, num_feature_inliers: int, matches: tuple, overlap: np.ndarray,
                     source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
                     prior: GravityPrior | None = None) -> RivalFigures:
    """The pose turned about each symmetry axis of the overlap and refined; the inliers of the
    pose and its rivals are counted on the same RIVAL_POINTS source keypoints (for speed). A truly
    symmetric scene also gives the rival feature support: symmetric places look alike. Under a
    gravity prior, a turn that tips the source over, or lifts its sensor out of the height band,
    is no rival (a road seen upside down)."""
    if len(overlap) < 3:
        return RivalFigures.of([])
    est, gate = config.estimation, config.acceptance
    sample = evenly_spaced(source.points, RIVAL_POINTS)
    own = len(point_refine(T, sample, target.neighbours, est.inlier_threshold, 0).source_index)
    rows = []
    turned = half_turns(overlap) @ T
    if prior is not None:
        turned = turned[prior.allows(turned, source, target)]
    for start in turned:
        refined = point_refine(start, sample, target.neighbours, est.inlier_threshold, RIVAL_ITERATIONS,
                               prior and prior.clamp)
        visibility = visibility_figures(refined.transform, source, target, gate, refined.target_index)
        rows.append((len(refined.source_index) / max(own, 1),
                     int(agreeing(refined.transform, *matches, config.initial.inlier_threshold).sum())
                     / max(num_feature_inliers, 1),
                     visibility.worst, visibility.opposite_sides, rotation_error_deg(refined.transform, T)))
    return RivalFigures.of(rows)
