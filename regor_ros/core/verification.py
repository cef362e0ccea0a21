"""verify(): judge a pose found elsewhere (a localization stack's, a SLAM back end's loop closure)
with register()'s gate, without a global search.

The pose is refined from where it was given, as the estimator refines a pose (point level, then
planes, until it settles), and the gate measures every figure there (gate/measure.py) and judges it with the one
judge. The feature matches are the search's (each source keypoint's nearest target descriptor), so
the test against chance is the search's own: the given pose is counted as the best of as many
poses as register()'s search would try on this source, since whoever found it searched too. Its
rivals are its symmetric twins (no search found other places); the surfaces' test, with decoys
around the pose, carries a pose the features do not, as in register().
A pose is verified when the refinement moved it by less than the verification tolerance and the
gate accepts the refined pose; a pose off by more is not, whatever the refined pose is (the
correction is reported, so a caller sees where the data put it). The refined pose is known only to
the keypoints' resolution (estimate.resolution_uncertainty: a voxel's standard deviation, and the
turn that moves the inliers' radius of gyration by as much), so the correction must stay within the
tolerance by that much: at the tolerance's edge the correction and the pose's error against the
truth fall on either side of it (results/verify_edge).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .config import RegorConfig
from .estimate import agreeing, pose_covariance, resolution_uncertainty
from .gate.figures import Figures
from .gate.judge import Rules, Verdict, judge
from .gate.measure import measure
from .gate.visibility import VisibilityFigures
from .gravity import GravityPrior
from .kernels import blas_on_one_thread
from .matching import match_features
from .metrics import rotation_error_deg, translation_error
from .pipeline import FROM_CLOUD, CloudInput, SourceInput, prepare_pair, refined_from
from .sequence import checked_pose
from .summary import Summary


@dataclass
class Verification:
    """verify()'s answer: whether the given pose is right, where the data put it, and every figure."""

    accepted: bool             # verified: right within the tolerance, and the gate accepts it there
    reason: str                # why not; empty when verified
    transform: np.ndarray      # 4x4 the refined pose T_target_source
    given: np.ndarray          # 4x4 the pose as given
    correction_m: float        # how far the refinement moved the given pose [m]
    correction_deg: float      # and turned it [deg]
    within_tolerance: bool     # the correction and the pose's uncertainty within verification.max_correction(_deg)
    verdict: Verdict           # the gate's on the refined pose
    figures: Figures
    covariance: np.ndarray     # 6x6 of the refined pose (as register()'s)
    visibility: VisibilityFigures
    timings: dict[str, float] = field(default_factory=dict)

    def summary(self) -> Summary:
        """The verdict, the correction and the figures, each under one name: for logs, status and
        JSON (Summary.as_json). ``accepted`` and ``reason`` are the verification's, not the gate's."""
        return dataclasses.replace(
            Summary.judged(self.verdict, self.figures, self.visibility, self.timings,
                           correction_m=float(self.correction_m), correction_deg=float(self.correction_deg),
                           within_tolerance=bool(self.within_tolerance)),
            accepted=self.accepted, reason=self.reason)


def verify(source: SourceInput, target: CloudInput, T_target_source, config: RegorConfig | None = None, *,
           source_viewpoint=FROM_CLOUD, target_viewpoint=FROM_CLOUD) -> Verification:
    """Whether ``T_target_source`` is right: the inputs as register() takes them (arrays, prepared
    clouds, a ScanSequence fused along odometry as the source); a map prepared for register()
    serves both. Raises RegistrationError for bad input (a pose that is not a finite rigid
    transform among it)."""
    with blas_on_one_thread():
        return _verify(source, target, T_target_source, (config or RegorConfig()).validate(),
                       source_viewpoint, target_viewpoint)


def _verify(source, target, given, config: RegorConfig, source_viewpoint, target_viewpoint) -> Verification:
    start = time.perf_counter()
    given = checked_pose(given, "the pose to verify")
    _, source, target, _ = prepare_pair(source, target, config, source_viewpoint, target_viewpoint)
    matches = match_features(source, target, 1, np.zeros(0, dtype=np.int64), mutual=False)
    prepared = time.perf_counter()
    prior = GravityPrior.of(config.gravity)
    voxel = config.features.voxel_size
    refined = refined_from(given, source, target, config, prior)
    T = refined.transform
    inliers_source, inliers_target = source.points[refined.source_index], target.points[refined.target_index]
    matched = target.points[matches.target_index]
    covariance = pose_covariance(T, inliers_source, inliers_target, target.normals[refined.target_index], voxel)
    uncertainty = resolution_uncertainty(T, inliers_source, voxel)
    searched = max(1, round(config.initial.seed_ratio * min(len(source), config.initial.max_correspondences)))
    measured = measure(refined, source, target,
                       (source.points, matched, agreeing(T, source.points, matched, config.initial.inlier_threshold)),
                       covariance=covariance, uncertainty=uncertainty,
                       hypotheses=searched, places=[], config=config, rules=Rules(config.acceptance),
                       refine=lambda pose: refined_from(pose, source, target, config, prior), prior=prior)
    verdict = judge(measured.figures, config.acceptance)
    moved_m, moved_deg = translation_error(T, given), rotation_error_deg(T, given)
    tolerance = config.verification
    known_m, known_deg = float(uncertainty[0]), float(np.degrees(uncertainty[1]))
    within = bool(moved_m + known_m < tolerance.max_correction and moved_deg + known_deg < tolerance.max_correction_deg)
    reason = verdict.reason if within else (
        f"the data put the pose {moved_m:.2f} m and {moved_deg:.1f} deg from where it was given, the "
        f"refined pose known to {known_m:.2f} m and {known_deg:.1f} deg at this resolution "
        f"(verification.max_correction={tolerance.max_correction:g} m, max_correction_deg="
        f"{tolerance.max_correction_deg:g}): the given pose is not right within them")
    return Verification(not reason, reason, T, given, moved_m, moved_deg, within, verdict, measured.figures,
                        covariance, measured.visibility,
                        {"features": prepared - start, "total": time.perf_counter() - start})
