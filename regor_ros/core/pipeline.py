"""register(): the whole Regor pipeline from two point clouds to a checked pose."""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .cloud import PreparedCloud, SeenCloud, check_viewpoint
from .config import RegorConfig
from .errors import RegistrationError
from .estimate import (
    agreeing,
    plane_refined,
    point_refine,
    point_refine_all,
    pose_covariance,
    poses_close,
    resolution_uncertainty,
    settled,
    weighted_kabsch,
)
from .features import ground_removed_between, prepare
from .gate.evidence import Evidence
from .gate.figures import Figures, RivalFigures
from .gate.judge import Rules, Verdict, judge, passes, undecided
from .gate.measure import measure, region_figures, reverse_figures
from .gate.visibility import VisibilityFigures, free_space_figures
from .gravity import GravityPrior, clamp_of
from .initial import initial_stage, led_by, same_place
from .kernels import blas_on_one_thread
from .matching import match_features
from .metrics import random_rigid_motion
from .regenerate import regenerate
from .search_region import SearchRegion, restrict
from .sequence import ScanSequence
from .summary import Summary
from .viewpoint import ORIGIN
from .visible_candidate import visible_candidate

CloudInput = np.ndarray | PreparedCloud
SourceInput = np.ndarray | PreparedCloud | ScanSequence
# the regenerated and the initial pose count as one when this close: no second refinement needed
SAME_POSE_DEG = 2.0
SAME_POSE_FRACTION = 0.5  # of the estimator's inlier threshold
REGRID_STREAM = 2  # keeps the retry rotations apart from other seeded draws of the same seed
# an attempt is measured, not judged: register() judges once, the pose it keeps
UNJUDGED = Verdict(False, "not judged yet", "unjudged")


@dataclass
class Correspondences:
    """Point pairs (source, target) with which of them agree with the pose."""

    source: np.ndarray   # (n, 3) source keypoints (source frame)
    target: np.ndarray   # (n, 3) target keypoints (target frame)
    inlier: np.ndarray   # (n,) bool, consistent with the estimated pose


@dataclass
class Candidate:
    """A distinct pose, with the FS-TCD support (feature-verified matches that agree in length)
    the search found at its place (0: none there). The result's first is its own pose, then the
    rivals the gate could not tell from it, then the other places the search found; the
    first's margin over the next says how unique the place is."""

    transform: np.ndarray   # 4x4 T_target_source
    support: int


@dataclass
class RegistrationResult:
    """register()'s answer: the pose, the gate's verdict and every figure behind it (the counts it
    reports are the figures', under their names)."""

    transform: np.ndarray          # 4x4 T_target_source: maps source points into the target frame
    figures: Figures               # everything the gate judged the pose on
    inlier_rmse: float             # RMS residual of the inliers [m]
    covariance: np.ndarray         # 6x6 over (x, y, z, roll, pitch, yaw), target frame
    initial: Correspondences       # all feature matches, inlier = within tau of the final pose
    final: Correspondences         # the estimator's point-level inlier pairs
    num_source_keypoints: int
    num_target_keypoints: int
    selected: str = "regeneration"  # which pose the estimator kept: "regeneration", "initial" or "candidate"
    stage_sizes: dict[str, int] = field(default_factory=dict)  # correspondences after each stage
    timings: dict[str, float] = field(default_factory=dict)    # seconds per stage
    attempts: int = 1  # registrations run: 1 + the acceptance.retries used
    visibility: VisibilityFigures = field(default_factory=lambda: VisibilityFigures(None, None))
    evidence: Evidence | None = None  # the pose's support against chance (core/gate/evidence.py)
    candidates: list[Candidate] = field(default_factory=list)  # this pose, then the other places found
    verdict: Verdict = UNJUDGED    # the quality gate's (core/gate/judge.py) on ``figures``

    @property
    def num_inliers(self) -> int:
        """Source keypoints with a target keypoint within tau_e after refinement."""
        return int(self.figures.num_inliers)

    @property
    def fitness(self) -> float:
        """num_inliers / source keypoints."""
        return float(self.figures.fitness)

    @property
    def feature_inliers(self) -> int:
        """Initial feature matches consistent with the pose."""
        return int(self.figures.feature_inliers)

    @property
    def accepted(self) -> bool:
        """Passed the quality gate (acceptance config)."""
        return self.verdict.accepted

    @property
    def reason(self) -> str:
        """Why it was not accepted; empty when accepted."""
        return self.verdict.reason

    @property
    def ambiguity(self) -> float | None:
        """The largest chance that a tie gives this pose its lead over a rival (gate/rivals.py)."""
        return self.verdict.ambiguity

    @property
    def rivals(self) -> RivalFigures:
        """The pose turned about the overlap's symmetry axes (core/gate/rivals.py)."""
        return self.figures.rivals

    @property
    def candidate_margin(self) -> float | None:
        """This pose's support over the best other place's (None when the search found no other)."""
        if len(self.candidates) < 2:
            return None
        return self.candidates[0].support / max(self.candidates[1].support, 1)

    def summary(self) -> Summary:
        """The verdict and every figure as plain values, each under one name: for logs, status
        messages, CSVs and JSON (Summary.as_json)."""
        return Summary.judged(self.verdict, self.figures, self.visibility, self.timings,
                              inlier_rmse=float(self.inlier_rmse), source_keypoints=self.num_source_keypoints,
                              target_keypoints=self.num_target_keypoints, selected=self.selected,
                              stage_sizes=dict(self.stage_sizes), attempts=self.attempts, evidence=self.evidence,
                              candidates=[int(c.support) for c in self.candidates],
                              candidate_margin=self.candidate_margin)


class _FromCloud:
    """The default viewpoint: the one a prepared cloud or scan sequence carries; the origin for a
    raw array (a scan in its sensor frame)."""

    def __repr__(self) -> str:
        return "FROM_CLOUD"


FROM_CLOUD = _FromCloud()


def prepare_cloud(points: np.ndarray | ScanSequence, config: RegorConfig, name: str = "cloud", *,
                  viewpoint=None, trajectory=None) -> PreparedCloud:
    """Prepare a cloud once (e.g. a static map) to pass to register() many times.

    ``viewpoint`` is the sensor position in the cloud's frame, or None (the default) for a cloud
    aggregated along a trajectory, a map: never assumed, since a wrong viewpoint makes the gate
    trust free space nobody saw. Give it for a single scan. ``trajectory`` (a map's (K, 4, 4)
    sensor poses or (K, 3) positions, in its frame) lets the gate also check the map's free space
    as seen from where it was built. A ScanSequence carries its own viewpoints.

    With the sensor positions known, the normals face them (features.normals_toward_sensors):
    register() then compares it only with a cloud whose sensor positions are known too. A cloud
    without viewpoint keeps its ground among its keypoints (features.ground_removed_between), and a
    scan registered against it keeps its own."""
    if isinstance(points, ScanSequence):
        if viewpoint is not None:
            raise RegistrationError(f"{name}: a scan sequence carries its viewpoints; give none")
        prepared = prepare(points.fused(), config.features, name, trajectory, rules=Rules(config.acceptance))
    else:
        prepared = prepare(SeenCloud.single(points, check_viewpoint(viewpoint, name)), config.features, name,
                           trajectory)
    prepared.index.built()  # a map's search is ready before its first query
    return prepared


def _raw(cloud: SourceInput, viewpoint, name: str) -> SeenCloud | PreparedCloud:
    """The input as a raw cloud with its viewpoints, or the prepared cloud whose viewpoints the
    given one must not contradict."""
    if isinstance(cloud, PreparedCloud):
        if viewpoint is not FROM_CLOUD:
            _check_same_viewpoint(cloud, check_viewpoint(viewpoint, name), name)
        return cloud
    if isinstance(cloud, ScanSequence):
        if viewpoint is not FROM_CLOUD:
            raise RegistrationError(f"{name}: a scan sequence carries its viewpoint (ScanSequence.viewpoint); "
                                    f"do not pass {name}_viewpoint")
        return cloud.fused()
    return SeenCloud.single(cloud, check_viewpoint(ORIGIN if viewpoint is FROM_CLOUD else viewpoint, name))


def _check_same_viewpoint(cloud: PreparedCloud, viewpoint: np.ndarray | None, name: str) -> None:
    own = cloud.viewpoints
    same = (own is None and viewpoint is None) or (
        own is not None and viewpoint is not None and len(own) == 1 and np.allclose(own[0], viewpoint))
    if not same:
        raise RegistrationError(
            f"{name}_viewpoint={None if viewpoint is None else viewpoint.tolist()} contradicts the "
            f"viewpoint the {name} was prepared with "
            f"({None if own is None else own.tolist()}); prepare it again with the right one")


def for_clouds_seen_from(config: RegorConfig, *viewpoints) -> RegorConfig:
    """``config`` for preparing the clouds of one registration one by one (a benchmark's pair, a
    batch row), given each one's viewpoint (None when unknown): their normals may face their
    sensors, and their ground leave the keypoints, only when every viewpoint is known, since
    register() refuses two clouds prepared under different conventions (_normals_toward_sensors,
    _ground_removed)."""
    if any(v is None for v in viewpoints):
        return config.replace({"features.normals_toward_sensors": False, "features.remove_ground": False})
    return config


def _normals_toward_sensors(source: SeenCloud | PreparedCloud, target: SeenCloud | PreparedCloud,
                            config: RegorConfig) -> bool:
    """Whether both clouds' normals face their sensors (features.normals_toward_sensors): FPFH
    compares only under one convention. A prepared cloud's is fixed and a raw one follows it; two
    raw clouds face their sensors when both know where theirs were."""
    clouds = {"source": source, "target": target}
    fixed = {name: c.normals_toward_sensors for name, c in clouds.items() if isinstance(c, PreparedCloud)}
    if len(set(fixed.values())) > 1:
        raise RegistrationError(
            "the source's and the target's normals were prepared under different conventions (one "
            "facing its sensors, one with the solver's signs), so their features do not compare; "
            "prepare both with their sensor positions known (viewpoint, or a map's trajectory), or "
            "both with features.normals_toward_sensors=false")
    if not fixed:
        return config.features.normals_toward_sensors and all(c.viewpoints is not None for c in clouds.values())
    toward = next(iter(fixed.values()))
    for name, cloud in clouds.items():
        if toward and isinstance(cloud, SeenCloud) and cloud.viewpoints is None:
            other = "target" if name == "source" else "source"
            raise RegistrationError(
                f"the {other}'s normals face its sensors but the {name}'s sensor position is unknown, "
                f"so their features do not compare; give {name}_viewpoint, or set "
                "features.normals_toward_sensors=false")
    return toward


def _ground_removed(source: SeenCloud | PreparedCloud, target: SeenCloud | PreparedCloud,
                    config: RegorConfig) -> bool:
    """Whether both clouds' keypoints leave out the ground (ground_removed_between): the features
    compare only when both did or neither. A prepared cloud's is fixed and a raw one follows it."""
    fixed = {c.ground_removed for c in (source, target) if isinstance(c, PreparedCloud)}
    if len(fixed) > 1:
        raise RegistrationError(
            "one cloud was prepared with its ground removed (a scan seen from a known sensor) and the "
            "other with its ground kept (a cloud without viewpoint, or prepared beside one), so their "
            "features do not compare; prepare them as one pair (for_clouds_seen_from), or both with "
            "features.remove_ground=false")
    if fixed:
        return fixed.pop()
    return ground_removed_between(config.features, source, target)


def _prepared(cloud: SeenCloud | PreparedCloud, config: RegorConfig, name: str,
              may_face_sensors: bool, remove_ground: bool) -> PreparedCloud:
    if isinstance(cloud, PreparedCloud):
        if cloud.config != config.features:
            raise RegistrationError(f"{name} was prepared with other feature settings; prepare it "
                                    "again with this configuration")
        return cloud
    return prepare(cloud, config.features, name, may_face_sensors=may_face_sensors, rules=Rules(config.acceptance),
                   remove_ground=remove_ground)


def prepare_pair(source: SourceInput, target: CloudInput, config: RegorConfig, source_viewpoint=FROM_CLOUD,
                 target_viewpoint=FROM_CLOUD):
    """(the raw source, or the prepared one given; both clouds prepared; whether their normals face
    their sensors): the inputs of register() and verify() checked and prepared as one pair."""
    raw_source, raw_target = _raw(source, source_viewpoint, "source"), _raw(target, target_viewpoint, "target")
    toward = _normals_toward_sensors(raw_source, raw_target, config)
    ground = _ground_removed(raw_source, raw_target, config)
    return (raw_source, _prepared(raw_source, config, "source", toward, ground),
            _prepared(raw_target, config, "target", toward, ground), toward)


def register(source: SourceInput, target: CloudInput, config: RegorConfig | None = None, *,
             source_viewpoint=FROM_CLOUD, target_viewpoint=FROM_CLOUD,
             search_region: SearchRegion | None = None) -> RegistrationResult:
    """Estimate T_target_source with no initial guess.

    ``source`` and ``target`` are (N, 3) arrays in metres or PreparedClouds; the source may also
    be a ScanSequence (scans fused along odometry: the pose is the newest scan's). Each viewpoint
    is the sensor position in that cloud's own frame, or None when unknown (a map aggregated along
    a trajectory). By default a raw array was seen from its origin (a single scan or camera
    frame) and a prepared cloud keeps the viewpoint it was prepared with; a viewpoint given for a
    prepared cloud must match it. Against a cloud with no viewpoint, the free-space check uses the
    map seen from where the pose puts the source's sensors.
    Raises RegistrationError when an input cannot be registered; a registered pose that fails
    the quality gate comes back with ``accepted=False`` and the reason (that of the first attempt).

    With acceptance.retries, a rejected raw source is registered again on a re-drawn voxel grid:
    how many FPFH matches are correct varies several-fold with the grid, so the search may find
    on another grid a place it missed. A retry publishes only another place than the first
    attempt's: the verdict on that one stands (on the 3DMatch lists, re-judging it published
    three shelf slides and a room of another building). A prepared source cannot be re-gridded
    and is not retried.

    ``search_region`` (a hint: where the source frame's origin is in the target frame, and how
    far off that may be) limits the search to the target keypoints the source can overlap from
    there, and a pose outside it is not accepted.
    """
    with blas_on_one_thread():
        return _register(source, target, config, source_viewpoint, target_viewpoint, search_region)


def _register(source, target, config, source_viewpoint, target_viewpoint, search_region) -> RegistrationResult:
    """register(), with numpy's BLAS on one thread."""
    config = (config or RegorConfig()).validate()
    start = time.perf_counter()
    # prepared once: the target for every attempt, the source also for the reverse check
    raw_source, prepared_source, target, toward = prepare_pair(source, target, config, source_viewpoint,
                                                               target_viewpoint)
    if search_region is not None:
        target = restrict(target, search_region, prepared_source)
    prepare_seconds = time.perf_counter() - start
    prior, acceptance = GravityPrior.of(config.gravity), config.acceptance
    result = _register_once(prepared_source, target, config, prior)
    attempts = 1
    while (not passes(result.figures, acceptance) and attempts <= acceptance.retries
           and isinstance(raw_source, SeenCloud)):
        turn = regrid_rotation(config.seed, attempts)
        regrid_start = time.perf_counter()
        try:
            turned = prepare(raw_source.moved(turn), config.features, "source", may_face_sensors=toward,
                             rules=Rules(acceptance), remove_ground=prepared_source.ground_removed)
        except RegistrationError:  # this grid keeps too few points: the verdict so far stands
            break
        retry = _register_once(turned, target, config, prior and prior.turned(turn[:3, :3]))
        retry.timings["features"] += time.perf_counter() - regrid_start
        attempts += 1
        if passes(retry.figures, acceptance):
            retry = _undo_turn(retry, turn)
            # the place the first attempt withheld keeps its verdict: a new grid is another draw
            # of the same figures, and a pose near a threshold would pass on one of a few draws
            if not same_place(retry.transform, result.transform, config.initial.inlier_threshold):
                result = retry
    result.attempts = attempts
    figures = result.figures
    if search_region is not None:
        figures = dataclasses.replace(figures, **region_figures(result.transform, search_region))
    if acceptance.reverse_check and passes(figures, acceptance):
        reverse = _register_once(target, prepared_source, config, prior and prior.swapped())
        figures = dataclasses.replace(figures, **reverse_figures(
            result.transform, np.linalg.inv(reverse.transform), config.initial.inlier_threshold))
    result.figures, result.verdict = figures, judge(figures, acceptance)
    result.timings["features"] += prepare_seconds
    result.timings["total"] = time.perf_counter() - start
    return result


def regrid_rotation(seed: int, attempt: int) -> np.ndarray:
    """The seeded rotation (4x4) that gives retry ``attempt`` its own voxel grid."""
    turn = random_rigid_motion([REGRID_STREAM, seed, attempt])
    turn[:3, 3] = 0.0
    return turn


def _undo_turn(result: RegistrationResult, turn: np.ndarray) -> RegistrationResult:
    """Express a result registered from the turned source in the source's own frame."""
    back = turn[:3, :3]  # a turned point p @ R^T goes back by @ R
    return dataclasses.replace(
        result, transform=result.transform @ turn,
        initial=dataclasses.replace(result.initial, source=result.initial.source @ back),
        final=dataclasses.replace(result.final, source=result.final.source @ back),
        candidates=[Candidate(c.transform @ turn, c.support) for c in result.candidates])


def _register_once(src_cloud: PreparedCloud, tgt_cloud: PreparedCloud, config: RegorConfig,
                   prior: GravityPrior | None) -> RegistrationResult:
    """One pass of the pipeline: features, matching, initial stage, regeneration, estimation, and
    every figure the gate judges, measured (``prior``: the gravity prior in these clouds' frames, or
    None)."""
    rules = Rules(config.acceptance)
    rng = np.random.default_rng(config.seed)
    timings: dict[str, float] = {}
    clock = time.perf_counter()
    start = clock

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = now - clock
        clock = now

    lap("features")

    fs_tcd_points = config.initial.fs_tcd_points
    candidate_rows = np.arange(len(src_cloud))
    if fs_tcd_points and len(src_cloud) > fs_tcd_points:
        candidate_rows = np.sort(rng.choice(len(src_cloud), fs_tcd_points, replace=False))
    matches = match_features(src_cloud, tgt_cloud, config.initial.candidates, candidate_rows,
                             mutual=config.initial.subset == "best")
    init_src = src_cloud.points
    init_tgt = tgt_cloud.points[matches.target_index]
    lap("matching")

    def plausible(T: np.ndarray) -> bool:
        return rules.free_space_passes(free_space_figures(T, src_cloud, tgt_cloud, config.acceptance))

    initial = initial_stage(init_src, init_tgt, src_cloud, tgt_cloud, matches, config.initial, rng,
                            plausible if config.initial.free_space_selection else None, prior)
    sizes = {"initial_matches": len(init_src), "initial_inliers": int(initial.inliers.sum())}
    lap("initial")

    seed_src, seed_tgt = init_src[initial.inliers], init_tgt[initial.inliers]
    regen = config.regeneration
    if regen.presample and len(seed_src):
        pick = rng.integers(0, len(seed_src), regen.presample)
        seed_src, seed_tgt = seed_src[pick], seed_tgt[pick]
    if len(seed_src):
        for stage, (k, s) in enumerate(zip(regen.stage_neighbors, regen.stage_seeds, strict=True), start=1):
            seed_src, seed_tgt = regenerate(seed_src, seed_tgt, src_cloud, tgt_cloud, k, s, regen, rng)
            sizes[f"stage{stage}"] = len(seed_src)
    lap("regeneration")

    refined, selected = _estimate(seed_src, seed_tgt, initial.transform, src_cloud, tgt_cloud, config, prior)
    if config.estimation.plane_refinement:
        refined = _plane_refine(refined, src_cloud, tgt_cloud, config, prior)
    if config.estimation.visible_candidates and not plausible(refined.transform):
        refined, selected = _visible_instead(refined, selected, initial.candidates, src_cloud, tgt_cloud, config,
                                             prior, plausible)
    refined = _refined_until_settled(refined, src_cloud, tgt_cloud, config, prior)
    T = refined.transform
    final_src = src_cloud.points[refined.source_index]
    final_tgt = tgt_cloud.points[refined.target_index]
    covariance = pose_covariance(T, final_src, final_tgt, tgt_cloud.normals[refined.target_index],
                                 config.features.voxel_size)
    uncertainty = resolution_uncertainty(T, final_src, config.features.voxel_size)
    lap("estimation")

    num_inliers = len(final_src)
    rmse = float(np.sqrt(np.mean(refined.distances ** 2))) if num_inliers else float("inf")
    initial_inlier = agreeing(T, init_src, init_tgt, config.initial.inlier_threshold)
    measured = measure(refined, src_cloud, tgt_cloud, (init_src, init_tgt, initial_inlier), covariance=covariance,
                       uncertainty=uncertainty, hypotheses=initial.hypotheses_tried,
                       places=[pose for pose, _ in initial.candidates], config=config, rules=rules,
                       refine=lambda pose: refined_from(pose, src_cloud, tgt_cloud, config, prior), prior=prior)
    lap("verification")
    timings["total"] = time.perf_counter() - start
    undecided_rivals = measured.rival_poses[undecided(measured.figures, config.acceptance)]
    return RegistrationResult(
        transform=T, figures=measured.figures, inlier_rmse=rmse, covariance=covariance,
        initial=Correspondences(init_src, init_tgt, initial_inlier),
        final=Correspondences(final_src, final_tgt, np.ones(num_inliers, dtype=bool)),
        num_source_keypoints=len(src_cloud), num_target_keypoints=len(tgt_cloud),
        selected=selected, stage_sizes=sizes, timings=timings, visibility=measured.visibility,
        evidence=measured.evidence,
        candidates=[Candidate(pose, support) for pose, support in
                    led_by([T, *undecided_rivals], initial.candidates,
                           config.initial.inlier_threshold)])


def _refine(T: np.ndarray, source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
            prior: GravityPrior | None):
    est = config.estimation
    return point_refine(T, source.points, target.neighbours, est.inlier_threshold, est.max_iterations,
                        clamp_of(prior))


def _plane_refine(refined, source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
                  prior: GravityPrior | None):
    return plane_refined(refined, source.points, target.neighbours, target.normals,
                         config.estimation.inlier_threshold, config.features.voxel_size, clamp_of(prior))


def _visible_instead(refined, selected: str, candidates: list, source: PreparedCloud, target: PreparedCloud,
                     config: RegorConfig, prior: GravityPrior | None, plausible):
    """(refinement, selected): the estimator's refinement of the best other place the search found
    that passes the free-space check, in place of ``refined`` (core/visible_candidate.py), or
    ``refined`` itself when there is none."""
    picked = visible_candidate(refined.transform, candidates, config.estimation.visible_candidates,
                               lambda poses: _refined_all(poses, source, target, config, prior), plausible,
                               config.initial.inlier_threshold)
    return (refined, selected) if picked is None else (picked, "candidate")


def _refined_until_settled(refined, source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
                           prior: GravityPrior | None):
    """``refined`` refined again by the estimator's rounds until it settles (estimate.settled,
    estimation.settle_rounds): register()'s last step, and verify()'s on the given pose."""
    return settled(refined, lambda T: _refined_all(T[None], source, target, config, prior)[0], source.points,
                   config.features.voxel_size, config.estimation.settle_rounds)


def refined_from(T: np.ndarray, source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
                 prior: GravityPrior | None):
    """The estimator's refinement of one pose (point level, then planes), settled."""
    return _refined_until_settled(_refined_all(T[None], source, target, config, prior)[0], source, target, config,
                                  prior)


def _refined_all(poses: np.ndarray, source: PreparedCloud, target: PreparedCloud, config: RegorConfig,
                 prior: GravityPrior | None) -> list:
    """The estimator's refinement of other poses (b, 4, 4): point level, stepped together, then
    planes when configured (each pose refines as it would alone)."""
    est = config.estimation
    point_level = point_refine_all(poses, source.points, target.neighbours, est.inlier_threshold,
                                   est.max_iterations, clamp_of(prior))
    if not est.plane_refinement:
        return point_level
    return [_plane_refine(refined, source, target, config, prior) for refined in point_level]


def _estimate(seed_src, seed_tgt, T_initial, source: PreparedCloud, target: PreparedCloud,
              config: RegorConfig, prior: GravityPrior | None):
    """Kabsch on the regenerated correspondences, then the point-level refinement (inside the
    gravity prior's tilt cone when there is one); keeps the initial pose instead when it refines
    to more inliers (compare_initial_pose)."""
    if len(seed_src) < 3:
        return _refine(T_initial, source, target, config, prior), "initial"
    refined = _refine(weighted_kabsch(seed_src, seed_tgt, clamp=clamp_of(prior)),
                      source, target, config, prior)
    est = config.estimation
    if est.compare_initial_pose and not poses_close(
            refined.transform, T_initial, SAME_POSE_DEG, SAME_POSE_FRACTION * est.inlier_threshold):
        alternative = _refine(T_initial, source, target, config, prior)
        if len(alternative.source_index) > len(refined.source_index):
            return alternative, "initial"
    return refined, "regeneration"
