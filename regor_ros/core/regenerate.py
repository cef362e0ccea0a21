"""Progressive correspondence regeneration (SPEC section 3), Regor's contribution.

Around trusted seed correspondences, new matches are found inside local regions of the full
keypoint sets (where feature matching is far less ambiguous than globally), filtered by
centre-aware three-point consistency, merged, and thinned by a global second-order filter.
Stages pass only coordinates to each other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .cloud import PreparedCloud
from .config import RegenerationConfig
from .consistency import top_second_order
from .geometry import unique_rows
from .matching import generalized_mutual_matches


@dataclass
class LocalMatches:
    """Matches of every region, compacted to the widest region: (regions, width) slots."""

    source_index: np.ndarray  # global source keypoint index, -1 in padded slots
    target_index: np.ndarray
    valid: np.ndarray
    count: np.ndarray         # (regions,) valid slots per region


def local_matches(seed_src: np.ndarray, seed_tgt: np.ndarray, source: PreparedCloud,
                  target: PreparedCloud, k: int, gmm_k: int) -> LocalMatches:
    """Group the k nearest keypoints around each seed on both sides and match them by GMM."""
    s = len(seed_src)
    _, near_p = source.tree.query(seed_src, k=k, workers=kernels.threads())
    _, near_q = target.tree.query(seed_tgt, k=k, workers=kernels.threads())
    near_p, near_q = near_p.reshape(s, k), near_q.reshape(s, k)
    similarity = source.features[near_p] @ np.swapaxes(target.features[near_q], 1, 2)
    rows, cols, count = generalized_mutual_matches(similarity, min(gmm_k, k))
    valid = rows >= 0
    src_idx = np.where(valid, np.take_along_axis(near_p, np.maximum(rows, 0), axis=1), -1)
    tgt_idx = np.where(valid, np.take_along_axis(near_q, np.maximum(cols, 0), axis=1), -1)
    return LocalMatches(src_idx, tgt_idx, valid, count)


def three_point_filter(seed_src: np.ndarray, seed_tgt: np.ndarray, m: LocalMatches,
                       source: PreparedCloud, target: PreparedCloud, cfg: RegenerationConfig,
                       padded_slots: int) -> np.ndarray:
    """Centre-aware three-point consistency (CTC): a match is kept if it agrees in length with
    its region's seed, or with enough of its region's matches; a region keeping too few of its
    matches is dropped whole (unless every region would be). Returns the kept-slot mask."""
    half = cfg.consistency_threshold / 2
    p = source.points[np.maximum(m.source_index, 0)]
    q = target.points[np.maximum(m.target_index, 0)]
    centre = np.abs(np.linalg.norm(p - seed_src[:, None], axis=2)
                    - np.linalg.norm(q - seed_tgt[:, None], axis=2)) < half
    support = kernels.region_agreement(p, q, m.valid, half)
    keep = m.valid & (centre | (support >= cfg.point_support_ratio * m.count[:, None]))
    kept = keep.sum(axis=1)
    if cfg.reproduce_ctc_padding_bug:
        # the authors' code pads to 2k slots pointing at keypoint 0 and counts their centre test
        p0, q0 = source.points[0], target.points[0]
        centre0 = np.abs(np.linalg.norm(p0 - seed_src, axis=1)
                         - np.linalg.norm(q0 - seed_tgt, axis=1)) < half
        kept = kept + (padded_slots - m.count) * centre0
    survives = (kept >= cfg.region_keep_ratio * m.count) & (m.count > 0)
    if not survives.any():
        survives = m.count > 0
    return keep & survives[:, None]


def global_filter(src: np.ndarray, tgt: np.ndarray, cfg: RegenerationConfig,
                  rng: np.random.Generator) -> np.ndarray:
    """Global second-order filter on the merged matches: top half by SC2 score, rescored inside
    that half, then the top 20 % of all. Returns indices into src/tgt."""
    candidates = np.arange(len(src))
    if cfg.global_cap and len(src) > cfg.global_cap:
        candidates = rng.choice(len(src), cfg.global_cap, replace=False)
    u = len(candidates)
    half = candidates[top_second_order(src[candidates], tgt[candidates], cfg.global_threshold, u // 2)]
    chosen = half[top_second_order(src[half], tgt[half], cfg.global_threshold, int(0.2 * u))]
    return chosen if len(chosen) >= 10 else candidates


def regenerate(seed_src: np.ndarray, seed_tgt: np.ndarray, source: PreparedCloud,
               target: PreparedCloud, k: int, s: int, cfg: RegenerationConfig,
               rng: np.random.Generator):
    """One regeneration stage with k neighbours and s seeds; returns new (src, tgt) coordinates,
    or the seeds unchanged when no region yields a consistent match."""
    k = min(k, len(source), len(target))
    pick = rng.integers(0, len(seed_src), s)
    centre_src, centre_tgt = seed_src[pick], seed_tgt[pick]
    m = local_matches(centre_src, centre_tgt, source, target, k, cfg.gmm_k)
    keep = three_point_filter(centre_src, centre_tgt, m, source, target, cfg, 2 * k)
    merged = unique_rows(np.stack([m.source_index[keep], m.target_index[keep]], axis=1))[0]
    if len(merged) == 0:
        return seed_src, seed_tgt
    src, tgt = source.points[merged[:, 0]], target.points[merged[:, 1]]
    chosen = global_filter(src, tgt, cfg, rng)
    return src[chosen], tgt[chosen]
