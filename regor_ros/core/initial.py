"""SC2-PCR++ initial stage (SPEC section 2): from feature matches to a first pose and its inliers.

Seeds with high spectral confidence grow second-order consensus sets; each gives a hypothesis,
the best by inlier count (or by candidate support) are compared by FS-TCD (how many
feature-verified matches agree in length with the best of them), and the winner is post-refined.
Its inliers seed regeneration.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from . import kernels
from .cloud import PreparedCloud
from .config import InitialConfig
from .consistency import compatibility, leading_eigenvector, second_order_top_k, seed_consensus, top_k_stable
from .estimate import agreeing, poses_close, post_refine, post_refine_all, weighted_kabsch
from .geometry import transform_points
from .gravity import GravityPrior
from .matching import FeatureMatches
from .places import DISTINCT_ANGLE_DEG, DISTINCT_TRANSLATION_FRACTION

DEDUPE_ANGLE_DEG = 1.0
DEDUPE_TRANSLATION_FRACTION = 0.2  # of the inlier threshold
SUPPORT_ROWS = 256  # source keypoints that rank hypotheses by candidate support


@dataclass
class InitialResult:
    """The initial stage's pose, its inlier correspondences and the distinct places it found."""

    transform: np.ndarray     # T_m, post-refined on all correspondences
    inliers: np.ndarray       # (N_c,) bool: correspondences within tau of T_m (G0)
    hypotheses_scored: int    # distinct hypotheses compared by FS-TCD
    hypotheses_tried: int     # poses the search generated and ranked (one per seed)
    candidates: list          # [(pose, FS-TCD support)] of distinct places, best supported first


def select_seeds(confidence: np.ndarray, points: np.ndarray, radius: float,
                 count: int) -> np.ndarray:
    """Non-maximum suppression in source space: local maxima of the confidence first (by
    confidence), then the rest in index order, as the authors' stable sort does."""
    neighbour_max = confidence.copy()
    if radius > 0:
        pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
        if len(pairs):
            np.maximum.at(neighbour_max, pairs[:, 0], confidence[pairs[:, 1]])
            np.maximum.at(neighbour_max, pairs[:, 1], confidence[pairs[:, 0]])
    score = confidence * (confidence >= neighbour_max)
    return np.argsort(-score, kind="stable")[:count]


def seed_hypotheses(src: np.ndarray, tgt: np.ndarray, cfg: InitialConfig,
                    prior: GravityPrior | None = None) -> np.ndarray:
    """One pose per seed from its two-stage consensus set and local spectral matching; (S, 4, 4).
    With a gravity prior, compatible correspondences also agree in height."""
    n = len(src)
    d = cfg.compatibility_threshold
    compatible = compatibility(src, tgt, d, None if prior is None else prior.height_offsets(src, tgt))

    confidence = leading_eigenvector(compatible, cfg.power_iterations)
    seeds = select_seeds(confidence, src, cfg.nms_radius, max(1, int(cfg.seed_ratio * n)))

    k1, k2 = (cfg.k1, cfg.k2) if cfg.k1 <= n else (4, 4)
    k1, k2 = min(k1, n), min(k2, n)
    first = second_order_top_k(compatible, seeds, k1)                    # C1, best first
    second, weights = seed_consensus(first, compatible, k2, cfg.power_iterations)
    weights = weights / (weights.sum(axis=1, keepdims=True) + 1e-6)
    return weighted_kabsch(src[second], tgt[second], weights.astype(np.float64))


def inlier_counts(transforms: np.ndarray, src: np.ndarray, tgt: np.ndarray,
                  threshold: float) -> np.ndarray:
    """Correspondences within ``threshold`` of each of a batch of poses, as one matrix product:
    |R a + t - b|^2 = |a|^2 + |b|^2 + |t|^2 + 2 a.(R^T t) - 2 t.b - 2 vec(R).vec(b a^T)
    on centred coordinates (for precision)."""
    a_mean, b_mean = src.mean(axis=0), tgt.mean(axis=0)
    a, b = src - a_mean, tgt - b_mean
    R = transforms[:, :3, :3]
    t = np.einsum("sij,j->si", R, a_mean) + transforms[:, :3, 3] - b_mean
    design = np.hstack([a, b, (b[:, :, None] * a[:, None, :]).reshape(-1, 9)])       # (n, 15)
    coeffs = np.hstack([2 * np.einsum("sji,sj->si", R, t), -2 * t, -2 * R.reshape(-1, 9)])  # (S, 15)
    sq = design @ coeffs.T + ((a ** 2).sum(1) + (b ** 2).sum(1))[:, None] + (t ** 2).sum(1)[None]
    return (sq < threshold ** 2).sum(axis=0)


def candidate_support(transforms: np.ndarray, source_points: np.ndarray,
                      candidate_points: np.ndarray, threshold: float) -> np.ndarray:
    """For each pose, how many of SUPPORT_ROWS source keypoints land within ``threshold`` of one
    of their K feature candidates: FS-TCD's verification step alone, cheap enough for every
    hypothesis. At low overlap the inlier count on a few thousand matches ranks the rare
    correct pose below the crowd; the candidates' fuller feature evidence does not."""
    rows = np.unique(np.linspace(0, len(source_points) - 1, SUPPORT_ROWS).astype(np.int64))
    rotations, translations = (np.ascontiguousarray(x) for x in (transforms[:, :3, :3], transforms[:, :3, 3]))
    return kernels.landed_counts(rotations, translations, np.ascontiguousarray(source_points[rows], dtype=np.float64),
                                 np.ascontiguousarray(candidate_points[:, rows]), np.float32(threshold ** 2))


def fs_tcd_fitness(poses: np.ndarray, source_points: np.ndarray, candidate_points: np.ndarray,
                   candidate_distance: np.ndarray, cfg: InitialConfig, rng: np.random.Generator) -> list:
    """FS-TCD score of each of a batch of poses (b, 4, 4): re-match every source keypoint to its
    most feature-similar candidate lying near its warped position, then count the largest set of
    these verified matches that agree in length with one of them. [(fitness, verified src,
    verified tgt)], one per pose, the poses' random draws in their order."""
    tau = cfg.inlier_threshold
    moved = np.stack([transform_points(T, source_points) for T in poses]).astype(np.float32)
    verified, best, residual = kernels.verified_candidates(moved, candidate_points, candidate_distance,
                                                           np.float32(tau ** 2), np.float32((1.5 * tau) ** 2))
    return [_length_agreement(np.flatnonzero(v), b, r, source_points, candidate_points, cfg, rng)
            for v, b, r in zip(verified, best, residual, strict=True)]


def _length_agreement(rows: np.ndarray, best: np.ndarray, residual: np.ndarray, source_points: np.ndarray,
                      candidate_points: np.ndarray, cfg: InitialConfig, rng: np.random.Generator):
    """One pose's FS-TCD score from its verified ``rows`` (their best candidates and residuals
    given for every row): (fitness, verified src, verified tgt)."""
    if not len(rows):
        return 0, source_points[:0], source_points[:0]
    best = best[rows]
    vp = source_points[rows]
    vq = candidate_points[:, rows, best].T.astype(np.float64)
    scored = np.arange(len(rows))
    if cfg.fs_tcd_rows and len(rows) > cfg.fs_tcd_rows:
        half = cfg.fs_tcd_rows // 2
        by_residual = np.argsort(residual[rows], kind="stable")
        rest = rng.choice(by_residual[half:], cfg.fs_tcd_rows - half, replace=False)
        scored = np.concatenate([by_residual[:half], rest])
    return int(kernels.most_length_agreement(vp, vq, scored, cfg.fs_tcd_threshold)), vp, vq


def consensus_subset(matches: FeatureMatches, cfg: InitialConfig, rng: np.random.Generator) -> np.ndarray:
    """The correspondences the quadratic consensus steps run on: all of them when they fit in
    max_correspondences, else a random subset (the authors' choice), or with subset="best" the
    mutual nearest neighbours first and then the most similar matches (deviation)."""
    n_all = len(matches.target_index)
    if not cfg.max_correspondences or n_all <= cfg.max_correspondences:
        return np.arange(n_all)
    if cfg.subset == "random":
        return np.sort(rng.choice(n_all, cfg.max_correspondences, replace=False))
    return matches.mutual_first(cfg.max_correspondences)


def _near_any(T: np.ndarray, poses: list, angle_deg: float, tolerance: float) -> bool:
    """Whether ``T`` is within ``angle_deg`` and ``tolerance`` of one of ``poses``. The positions,
    compared with all of them at once, pick the few worth the exact test (with a margin far above
    rounding, so the answer is the exact test's)."""
    if not poses:
        return False
    offsets = np.linalg.norm(np.array([K[:3, 3] for K in poses]) - T[:3, 3], axis=1)
    return any(poses_close(T, poses[i], angle_deg, tolerance)
               for i in np.flatnonzero(offsets < tolerance * (1 + 1e-9)))


def _fittest(poses: list, fitnesses: list, plausible) -> np.ndarray:
    """The pose of highest fitness (the first on ties), among the plausible ones when any is."""
    order = np.argsort(-np.asarray(fitnesses), kind="stable")
    if plausible is not None:
        for i in order:
            if plausible(poses[i]):
                return poses[i]
    return poses[order[0]]


def initial_stage(src: np.ndarray, tgt: np.ndarray, source: PreparedCloud, target: PreparedCloud,
                  matches: FeatureMatches, cfg: InitialConfig, rng: np.random.Generator,
                  plausible: Callable[[np.ndarray], bool] | None = None,
                  prior: GravityPrior | None = None) -> InitialResult:
    """Run SC2-PCR++ on the correspondences (src[i], tgt[i]) and return T_m with its inliers.

    With ``plausible`` (a pose -> bool check, e.g. free space), FS-TCD's winner is the fittest
    plausible hypothesis, or the fittest of all when none is plausible. With a gravity ``prior``,
    hypotheses come from height-consistent consensus sets, those outside its tilt cone or height
    band are dropped before they are ranked (fewer to compare), and every refinement stays inside
    the cone."""
    subset = consensus_subset(matches, cfg, rng)
    sub_src, sub_tgt = src[subset], tgt[subset]
    clamp = None if prior is None else prior.clamp

    hypotheses = seed_hypotheses(sub_src, sub_tgt, cfg, prior)
    if prior is not None:
        keeps = prior.allows(hypotheses, source, target)
        if keeps.any():
            hypotheses = hypotheses[keeps]

    def most_inliers() -> np.ndarray:
        """T_ic, the hypothesis with the most inliers in the consensus subset: the fallback when
        FS-TCD compared none or T_m has no inliers (computed only then)."""
        return hypotheses[int(np.argmax(inlier_counts(hypotheses, sub_src, sub_tgt, cfg.inlier_threshold)))]

    # FS-TCD works on the candidates' x, y, z planes, relative to their centroid (float32; not
    # the target's: a map's would cost a pass over the map on every call)
    origin = target.points[matches.candidates[:, 0]].mean(axis=0)
    candidate_points = np.empty((3, *matches.candidates.shape), dtype=np.float32)
    for axis in range(3):   # an axis at a time: a third of the temporaries of gathering the rows
        candidate_points[axis] = target.points[:, axis][matches.candidates] - origin[axis]
    shift = np.eye(4)
    shift[:3, 3] = -origin
    candidate_sources = source.points[matches.candidate_rows]
    if cfg.ranking == "inliers":
        scores = inlier_counts(hypotheses, sub_src, sub_tgt, cfg.inlier_threshold)
    else:
        scores = candidate_support(shift @ hypotheses, candidate_sources, candidate_points, cfg.inlier_threshold)
    ranked = top_k_stable(scores, cfg.num_hypotheses)
    kept: list = []
    fitnesses: list = []
    tolerance = DEDUPE_TRANSLATION_FRACTION * cfg.inlier_threshold

    def score(poses: list) -> list:
        return fs_tcd_fitness(np.array([shift @ T for T in poses]), candidate_sources, candidate_points,
                              matches.candidate_distance, cfg, rng)

    if cfg.reproduce_fs_tcd_quirk:
        # each hypothesis refined on the previous one's verified matches: one at a time
        refine_src, refine_tgt = src, tgt
        for h in ranked:
            T = post_refine(hypotheses[h], refine_src, refine_tgt, cfg.refine_threshold, 1, clamp)
            if cfg.dedupe_hypotheses and _near_any(T, kept, DEDUPE_ANGLE_DEG, tolerance):
                continue
            kept.append(T)
            ((fitness, verified_src, verified_tgt),) = score([T])
            if len(verified_src) >= 3:
                refine_src, refine_tgt = verified_src, verified_tgt + origin
            fitnesses.append(fitness)
    else:
        # one refinement step each, all at once, and FS-TCD on every distinct one at once
        for T in post_refine_all(hypotheses[ranked], src, tgt, cfg.refine_threshold, 1, clamp):
            if not (cfg.dedupe_hypotheses and _near_any(T, kept, DEDUPE_ANGLE_DEG, tolerance)):
                kept.append(T)
        fitnesses = [fitness for fitness, _, _ in score(kept)] if kept else []
    T_fs = _fittest(kept, fitnesses, plausible) if kept else most_inliers()

    T_m = post_refine(T_fs, src, tgt, cfg.refine_threshold, 20, clamp)
    inliers = agreeing(T_m, src, tgt, cfg.inlier_threshold)
    if not inliers.any():
        inliers = agreeing(most_inliers(), src, tgt, cfg.inlier_threshold)
    return InitialResult(T_m, inliers, len(kept), len(hypotheses),
                         distinct_candidates(kept, fitnesses, cfg.inlier_threshold))


def near_place(T: np.ndarray, poses: list, inlier_threshold: float) -> bool:
    """Whether ``T`` is one place of the search with one of ``poses``: within DISTINCT_ANGLE_DEG
    and DISTINCT_TRANSLATION_FRACTION x tau of it."""
    return _near_any(T, poses, DISTINCT_ANGLE_DEG, DISTINCT_TRANSLATION_FRACTION * inlier_threshold)


def same_place(A: np.ndarray, B: np.ndarray, inlier_threshold: float) -> bool:
    """Whether two poses are one place of the search (near_place)."""
    return near_place(A, [B], inlier_threshold)


def distinct_candidates(poses: list, supports: list, inlier_threshold: float) -> list:
    """[(pose, support)] best first, each at another place (same_place) than every better-supported
    one: the places the search found, so a user sees how far ahead the winner is (a road or a row
    of trees offers several)."""
    out: list = []
    for i in np.argsort(-np.asarray(supports, dtype=np.float64), kind="stable"):
        if not near_place(poses[i], [kept for kept, _ in out], inlier_threshold):
            out.append((poses[i], int(supports[i])))
    return out


def led_by(leaders: list, candidates: list, inlier_threshold: float) -> list:
    """The ``leaders`` (the final pose, then the rivals the gate could not tell from it) first,
    each carrying the best support of the candidates at its place, then the other candidates
    (best supported first): the published pose and its rivals."""
    def support_at(T):
        return max((s for pose, s in candidates if same_place(pose, T, inlier_threshold)), default=0)
    return [(T, support_at(T)) for T in leaders] + [
        (pose, s) for pose, s in candidates if not near_place(pose, leaders, inlier_threshold)]
