"""SC2-PCR++ initial stage (SPEC section 2): from feature matches to a first pose and its inliers.

Seeds with high spectral confidence grow second-order consensus sets; each gives a hypothesis,
the best by inlier count are compared by FS-TCD (how many feature-verified matches agree in
length with the best of them), and the winner is post-refined. Its inliers seed regeneration.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .config import InitialConfig
from .consistency import leading_eigenvector, length_residual
from .estimate import post_refine, transform_points, weighted_kabsch
from .features import PreparedCloud
from .matching import FeatureMatches, feature_distance

DEDUPE_ANGLE_DEG = 1.0
DEDUPE_TRANSLATION_FRACTION = 0.2  # of the inlier threshold


@dataclass
class InitialResult:
    transform: np.ndarray     # T_m, post-refined on all correspondences
    inliers: np.ndarray       # (N_c,) bool: correspondences within tau of T_m (G0)
    hypotheses_scored: int    # distinct hypotheses compared by FS-TCD


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


def seed_hypotheses(src: np.ndarray, tgt: np.ndarray, cfg: InitialConfig) -> np.ndarray:
    """One pose per seed from its two-stage consensus set and local spectral matching; (S, 4, 4)."""
    n = len(src)
    d = cfg.compatibility_threshold
    residual = length_residual(src, tgt).astype(np.float32)
    soft = np.maximum(0.0, 1.0 - residual ** 2 / d ** 2)
    hard = (residual < d).astype(np.float32)
    tight = (residual < d / 2).astype(np.float32)
    del residual

    confidence = leading_eigenvector(soft, cfg.power_iterations)
    seeds = select_seeds(confidence, src, cfg.nms_radius, max(1, int(cfg.seed_ratio * n)))

    k1, k2 = (cfg.k1, cfg.k2) if cfg.k1 <= n else (4, 4)
    k1, k2 = min(k1, n), min(k2, n)
    sc2 = (tight[seeds] @ tight) * hard[seeds]                          # (S, n)
    first = np.argsort(-sc2, axis=1, kind="stable")[:, :k1]              # C1, best first
    hard_first = hard[first[:, :, None], first[:, None, :]]              # (S, k1, k1)
    # second stage: agreement with the best member c* of C1, through C1
    score = np.einsum("sm,smj->sj", hard_first[:, 0, :], hard_first)
    second = np.take_along_axis(first, np.argsort(-score, axis=1, kind="stable")[:, :k2], axis=1)
    local = soft[second[:, :, None], second[:, None, :]].copy()          # (S, k2, k2)
    diag = np.arange(local.shape[1])
    local[:, diag, diag] = 0.0
    weights = leading_eigenvector(local, cfg.power_iterations)
    weights = weights / (weights.sum(axis=1, keepdims=True) + 1e-6)
    return weighted_kabsch(src[second], tgt[second], weights.astype(np.float64))


def inlier_counts(transforms: np.ndarray, src: np.ndarray, tgt: np.ndarray,
                  threshold: float) -> np.ndarray:
    """Correspondences within ``threshold`` of each of a batch of poses."""
    moved = np.einsum("sij,nj->sni", transforms[:, :3, :3], src) + transforms[:, None, :3, 3]
    return (((moved - tgt) ** 2).sum(axis=2) < threshold ** 2).sum(axis=1)


def fs_tcd_fitness(T: np.ndarray, source: PreparedCloud, target: PreparedCloud,
                   matches: FeatureMatches, cfg: InitialConfig, rng: np.random.Generator):
    """FS-TCD score of a pose: re-match every source keypoint to its most feature-similar
    candidate lying near its warped position, then count the largest set of these verified
    matches that agree in length with one of them. Returns (fitness, verified src, verified tgt)."""
    tau = cfg.inlier_threshold
    moved = transform_points(T, source.points)
    k = min(cfg.fs_tcd_ball_neighbors, len(target))
    dist, idx = target.tree.query(moved, k=k, distance_upper_bound=1.5 * tau, workers=-1)
    dist, idx = dist.reshape(len(moved), k), idx.reshape(len(moved), k)
    near = idx < len(target)
    idx_safe = np.where(near, idx, 0)
    sim = np.einsum("nc,nkc->nk", source.features, target.features[idx_safe])
    candidate = near & (sim >= matches.candidate_floor[:, None])
    verified = (candidate & (dist <= tau)).any(axis=1)
    if not verified.any():
        return 0, source.points[:0], target.points[:0]
    cost = np.where(candidate, feature_distance(sim), np.inf)[verified]
    best = np.argmin(cost, axis=1)
    rows = np.flatnonzero(verified)
    vp = source.points[rows]
    vq = target.points[idx_safe[rows, best]]
    scored = np.arange(len(rows))
    if cfg.fs_tcd_rows and len(rows) > cfg.fs_tcd_rows:
        half = cfg.fs_tcd_rows // 2
        by_residual = np.argsort(dist[rows, best], kind="stable")
        rest = rng.choice(by_residual[half:], cfg.fs_tcd_rows - half, replace=False)
        scored = np.concatenate([by_residual[:half], rest])
    dp = np.linalg.norm(vp[scored, None, :] - vp[None, :, :], axis=2)
    dq = np.linalg.norm(vq[scored, None, :] - vq[None, :, :], axis=2)
    fitness = int((np.abs(dp - dq) < cfg.fs_tcd_threshold).sum(axis=1).max())
    return fitness, vp, vq


def _is_duplicate(T: np.ndarray, kept: list, translation_tol: float) -> bool:
    for K in kept:
        cos = (np.trace(T[:3, :3].T @ K[:3, :3]) - 1.0) / 2.0
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        if angle < DEDUPE_ANGLE_DEG and np.linalg.norm(T[:3, 3] - K[:3, 3]) < translation_tol:
            return True
    return False


def initial_stage(src: np.ndarray, tgt: np.ndarray, source: PreparedCloud, target: PreparedCloud,
                  matches: FeatureMatches, cfg: InitialConfig,
                  rng: np.random.Generator) -> InitialResult:
    """Run SC2-PCR++ on the correspondences (src[i], tgt[i]) and return T_m with its inliers."""
    n_all = len(src)
    subset = np.arange(n_all)
    if cfg.max_correspondences and n_all > cfg.max_correspondences:
        subset = np.sort(rng.choice(n_all, cfg.max_correspondences, replace=False))
    sub_src, sub_tgt = src[subset], tgt[subset]

    hypotheses = seed_hypotheses(sub_src, sub_tgt, cfg)
    counts = inlier_counts(hypotheses, sub_src, sub_tgt, cfg.inlier_threshold)
    T_ic = hypotheses[int(np.argmax(counts))]
    ranked = np.argsort(-counts, kind="stable")[:cfg.num_hypotheses]

    best_fitness, T_fs = -1, T_ic
    kept: list = []
    refine_src, refine_tgt = src, tgt
    for h in ranked:
        T = post_refine(hypotheses[h], refine_src, refine_tgt, cfg.refine_threshold, 1)
        if cfg.dedupe_hypotheses and _is_duplicate(
                T, kept, DEDUPE_TRANSLATION_FRACTION * cfg.inlier_threshold):
            continue
        kept.append(T)
        fitness, verified_src, verified_tgt = fs_tcd_fitness(T, source, target, matches, cfg, rng)
        if cfg.reproduce_fs_tcd_quirk and len(verified_src) >= 3:
            refine_src, refine_tgt = verified_src, verified_tgt
        if fitness > best_fitness:
            best_fitness, T_fs = fitness, T

    T_m = post_refine(T_fs, src, tgt, cfg.refine_threshold, 20)
    inliers = np.linalg.norm(transform_points(T_m, src) - tgt, axis=1) < cfg.inlier_threshold
    if not inliers.any():
        inliers = np.linalg.norm(transform_points(T_ic, src) - tgt, axis=1) < cfg.inlier_threshold
    return InitialResult(T_m, inliers, len(kept))
