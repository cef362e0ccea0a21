"""Matching in FPFH feature space: global nearest neighbours and local generalized mutual matching.

Features are unit vectors, so the feature distance sqrt(2 - 2 f.g) is monotone in the dot
product; everything here ranks by similarity (dot product) and never takes the square root.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .cloud import PreparedCloud


@dataclass
class FeatureMatches:
    """One-way nearest neighbour of every source keypoint, and its K most similar targets."""

    target_index: np.ndarray        # (N,) nearest target keypoint in feature space
    similarity: np.ndarray          # (N,) its feature similarity (dot product)
    mutual: np.ndarray | None    # (N,) the source keypoint is also its target's nearest (if asked)
    candidate_rows: np.ndarray      # (R,) source keypoints that have candidate sets
    candidates: np.ndarray          # (R, K) their K most similar target keypoints (FS-TCD's set)
    candidate_distance: np.ndarray  # (R, K) and feature distances


def feature_distance(similarity: np.ndarray) -> np.ndarray:
    """The spec's feature distance delta = sqrt(2 - 2 f.g + 1e-6) from a dot product."""
    return np.sqrt(np.maximum(2.0 - 2.0 * similarity + 1e-6, 0.0))


def match_features(source: PreparedCloud, target: PreparedCloud, candidates: int,
                   candidate_rows: np.ndarray, mutual: bool = True) -> FeatureMatches:
    """Nearest target feature per source feature (no mutual check, as the authors run it) and the
    ``candidates`` most similar targets of the source features in ``candidate_rows``, most
    similar first. Only the target's index is searched, so a map costs an index query per
    source keypoint. With ``mutual``, the flags say which source keypoints are also their
    target's most similar source keypoint (an exact target index finds that in the same
    products; an inverted file has the source's index searched for the targets hit)."""
    nearest, best_sim, cand, cand_sim, back = target.index.nearest_and_candidates(
        source.features, candidate_rows, candidates, back=mutual)
    nearest = np.maximum(nearest, 0)
    missing = cand < 0  # an inverted file found fewer than K: repeat the row's best instead
    if missing.any():
        cand = np.where(missing, cand[:, :1], cand)
        cand_sim = np.where(missing, cand_sim[:, :1], cand_sim)
    flags = None
    if mutual:
        if back is None:  # an inverted file: the source's index answers for the targets hit
            hit = np.unique(nearest)
            back = np.zeros(len(target.features), dtype=np.int64)
            back[hit] = source.index.search(target.features[hit], 1)[0][:, 0]
        flags = back[nearest] == np.arange(len(nearest))
    return FeatureMatches(nearest, best_sim, flags, candidate_rows, cand, feature_distance(cand_sim))


def generalized_mutual_matches(similarity: np.ndarray, k: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Generalized mutual matching (GMM): keep (j, l) if l is j's nearest and j is among l's k
    nearest, or j is l's nearest and l among j's k nearest, in each region of (regions, rows,
    cols) similarities. It contains the mutual matches (k = 1) and holds at most rows + cols
    pairs. Ties go to the lower index. (rows, cols: (regions, width), -1 past each region's
    count; count (regions,)), each region's pairs in row-major order, width the most any holds."""
    rows, cols, count = kernels.generalized_mutual_pairs(np.ascontiguousarray(similarity), int(k))
    width = max(int(count.max(initial=0)), 1)
    return rows[:, :width], cols[:, :width], count
