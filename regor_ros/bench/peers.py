"""The registration methods the benchmark compares, behind one signature.

Every method gets the same raw clouds and, where it takes features, the same prepared keypoints
and FPFH features (the preparation is timed once, outside the methods). KISS-Matcher computes
its own features from the raw clouds at the same voxel size; it is an optional dependency.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from ..core import PreparedCloud, RegorConfig, Summary, register, to_matrix


@dataclass
class MethodResult:
    transform: np.ndarray
    seconds: float                          # registration time, features excluded
    includes_features: bool = False         # True when ``seconds`` covers its own features
    final: tuple | None = None           # (source, target) final correspondences
    initial: tuple | None = None         # (source, target) initial correspondences
    accepted: bool | None = None         # the method's own quality verdict, if it has one
    summary: Summary | None = None       # Regor's verdict and figures


NO_PRIOR = {"gravity.source_up": "unknown", "gravity.target_up": "unknown"}
PLANE = {"estimation.plane_refinement": True}


def _regor_variant(overrides: dict) -> Callable:
    def run(src: PreparedCloud, tgt: PreparedCloud, raw_src, raw_tgt, config: RegorConfig, seed: int):
        cfg = config.replace({**overrides, "seed": seed})
        # retries re-grid the raw source, seen from where the prepared one was
        viewpoint = None if src.viewpoints is None else src.viewpoints[0]
        r = (register(raw_src, tgt, cfg, source_viewpoint=viewpoint) if cfg.acceptance.retries
             else register(src, tgt, cfg))
        return MethodResult(r.transform, r.timings["total"] - r.timings["features"],
                            final=(r.final.source, r.final.target),
                            initial=(r.initial.source, r.initial.target), accepted=r.accepted,
                            summary=r.summary())
    return run


def _o3d_inputs(cloud: PreparedCloud):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    feature = o3d.pipelines.registration.Feature()
    feature.data = cloud.features.T.astype(np.float64)
    return pcd, feature


def _o3d_result(result, src: PreparedCloud, tgt: PreparedCloud, seconds: float) -> MethodResult:
    pairs = np.asarray(result.correspondence_set, dtype=np.int64).reshape(-1, 2)
    return MethodResult(np.array(result.transformation), seconds,
                        final=(src.points[pairs[:, 0]], tgt.points[pairs[:, 1]]))


def open3d_ransac(src, tgt, raw_src, raw_tgt, config: RegorConfig, seed: int) -> MethodResult:
    """Open3D FPFH + RANSAC with mutual filter, edge-length and distance checkers, 100k iterations."""
    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    (ps, fs), (pt, ft) = _o3d_inputs(src), _o3d_inputs(tgt)
    threshold = config.initial.inlier_threshold
    start = time.perf_counter()
    result = reg.registration_ransac_based_on_feature_matching(
        ps, pt, fs, ft, True, threshold, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
         reg.CorrespondenceCheckerBasedOnDistance(threshold)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    return _o3d_result(result, src, tgt, time.perf_counter() - start)


def open3d_fgr(src, tgt, raw_src, raw_tgt, config: RegorConfig, seed: int) -> MethodResult:
    """Open3D Fast Global Registration on the same FPFH features."""
    reg = o3d.pipelines.registration
    (ps, fs), (pt, ft) = _o3d_inputs(src), _o3d_inputs(tgt)
    option = reg.FastGlobalRegistrationOption(
        maximum_correspondence_distance=config.initial.inlier_threshold)
    start = time.perf_counter()
    result = reg.registration_fgr_based_on_feature_matching(ps, pt, fs, ft, option)
    return _o3d_result(result, src, tgt, time.perf_counter() - start)


def kiss_matcher_solution(source: np.ndarray, target: np.ndarray, voxel_size: float):
    """(T_target_source, seconds, its valid flag, its final inlier count) of KISS-Matcher (pip
    kiss-matcher) on raw clouds: the count is what its users threshold to trust a pose."""
    import kiss_matcher as km
    matcher = km.KISSMatcher(km.KISSMatcherConfig(voxel_size))
    start = time.perf_counter()
    solution = matcher.estimate(np.asarray(source, np.float32), np.asarray(target, np.float32))
    seconds = time.perf_counter() - start
    return (to_matrix(np.asarray(solution.rotation), np.asarray(solution.translation).reshape(3)), seconds,
            bool(solution.valid), int(matcher.get_num_final_inliers()))


def kiss_matcher_pose(source: np.ndarray, target: np.ndarray, voxel_size: float):
    """(T_target_source, seconds, its valid flag) of KISS-Matcher on raw clouds."""
    return kiss_matcher_solution(source, target, voxel_size)[:3]


def kiss_matcher(src, tgt, raw_src, raw_tgt, config: RegorConfig, seed: int) -> MethodResult:
    """KISS-Matcher on the raw clouds, at the same voxel size."""
    T, seconds, valid = kiss_matcher_pose(raw_src, raw_tgt, config.features.voxel_size)
    return MethodResult(T, seconds, includes_features=True, accepted=valid)


METHODS: dict[str, Callable] = {
    "regor": _regor_variant({}),
    "regor-1stage": _regor_variant({"stage_neighbors": [20], "stage_seeds": [500]}),
    "sc2pcr++": _regor_variant({"stage_neighbors": [], "stage_seeds": []}),
    "regor-retry3": _regor_variant({"retries": 3}),
    "regor-noprior": _regor_variant(NO_PRIOR),
    "regor-retry3-noprior": _regor_variant({"retries": 3, **NO_PRIOR}),
    "regor-reverse": _regor_variant({"reverse_check": True}),
    "regor-fss": _regor_variant({"free_space_selection": True}),
    "regor-plane": _regor_variant(PLANE),
    "o3d-ransac": open3d_ransac,
    "o3d-fgr": open3d_fgr,
    "kiss-matcher": kiss_matcher,
}

DESCRIPTIONS = {
    "regor": "Regor as configured (SC2-PCR++ initial stage, two regeneration stages, estimator)",
    "regor-1stage": "Regor with one regeneration stage (k=20, s=500), the paper's fast ablation",
    "sc2pcr++": "SC2-PCR++ initial stage alone, then the same point-level estimator (ablation)",
    "regor-retry3": "Regor with acceptance.retries=3: a rejected pose is registered again on up to 3 re-drawn voxel "
                    "grids",
    "regor-noprior": "Regor without the gravity prior (the up directions unknown), whatever the run gives it",
    "regor-retry3-noprior": "regor-retry3 without the gravity prior",
    "regor-reverse": "Regor with acceptance.reverse_check: an accepted pose must come back from the "
                     "target-to-source registration",
    "regor-fss": "Regor with initial.free_space_selection: FS-TCD picks the fittest hypothesis that passes the "
                 "free-space check",
    "regor-plane": "Regor with estimation.plane_refinement: the pose refined point-to-plane after the point level",
    "o3d-ransac": "Open3D FPFH + RANSAC, mutual filter, edge 0.9 + distance checkers, 100k iterations",
    "o3d-fgr": "Open3D Fast Global Registration on the same features",
    "kiss-matcher": "KISS-Matcher 1.0 (pip), own features at the same voxel size",
}
