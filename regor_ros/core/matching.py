"""Matching in FPFH feature space: global nearest neighbours and local generalized mutual matching.

Features are unit vectors, so the feature distance sqrt(2 - 2 f.g) is monotone in the dot
product; everything here ranks by similarity (dot product) and never takes the square root.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import kernels
from .cloud import PreparedCloud

MUTUAL_CHECKS = 2  # mutual_first asks about twice as many matches as it still needs mutual ones


@dataclass
class FeatureMatches:
    """One-way nearest neighbour of every source keypoint, and its K most similar targets."""

    target_index: np.ndarray        # (N,) nearest target keypoint in feature space
    similarity: np.ndarray          # (N,) its feature similarity (dot product)
    back: Callable[[np.ndarray], np.ndarray] | None  # target keypoints -> each one's most similar source keypoint
    candidate_rows: np.ndarray      # (R,) source keypoints that have candidate sets
    candidates: np.ndarray          # (R, K) their K most similar target keypoints (FS-TCD's set)
    candidate_distance: np.ndarray  # (R, K) and feature distances

    def mutual(self, rows: np.ndarray) -> np.ndarray:
        """Whether each source keypoint of ``rows`` is also its target's most similar one."""
        if self.back is None:
            raise ValueError("these matches were found without the search back (match_features(mutual=False))")
        rows = np.asarray(rows, dtype=np.int64)
        return self.back(self.target_index[rows]) == rows

    def mutual_first(self, count: int) -> np.ndarray:
        """``count`` matches, in source order: the mutual ones first, then the others, each group
        most similar first (ties to the lower source keypoint). Matches are checked in that
        order, a few more at a time than the mutual ones still missing, and no further than the
        count needs: against a map each check is a pass over the source's features."""
        order = np.argsort(-self.similarity, kind="stable")
        if self.back is None:
            return np.sort(order[:count])
        taken: list[np.ndarray] = []
        found = checked = 0
        while found < count and checked < len(order):
            rows = order[checked:checked + MUTUAL_CHECKS * (count - found)]
            taken.append(rows[self.mutual(rows)])
            found += len(taken[-1])
            checked += len(rows)
        chosen = np.concatenate(taken) if taken else order[:0]
        if found < count:  # every match was checked: the most similar of the others fill the rest
            other = np.ones(len(order), dtype=bool)
            other[chosen] = False
            chosen = np.concatenate([chosen, order[other[order]]])
        return np.sort(chosen[:count])


def feature_distance(similarity: np.ndarray) -> np.ndarray:
    """The spec's feature distance delta = sqrt(2 - 2 f.g + 1e-6) from a dot product."""
    return np.sqrt(np.maximum(2.0 - 2.0 * similarity + 1e-6, 0.0))


def match_features(source: PreparedCloud, target: PreparedCloud, candidates: int,
                   candidate_rows: np.ndarray, mutual: bool = True) -> FeatureMatches:
    """Nearest target feature per source feature (no mutual check, as the authors run it) and the
    ``candidates`` most similar targets of the source features in ``candidate_rows``, most
    similar first. Only the target's index is searched, so a map costs an index query per
    source keypoint. With ``mutual``, the matches can say which source keypoints are also their
    target's most similar source keypoint (FeatureMatches.mutual): an exact target index finds
    that in the same products; against an inverted file (a map) the source's features are
    searched exactly for the targets asked about, when they are asked about."""
    nearest, best_sim, cand, cand_sim, back = target.index.nearest_and_candidates(
        source.features, candidate_rows, candidates, back=mutual)
    nearest = np.maximum(nearest, 0)
    missing = cand < 0  # an inverted file found fewer than K: repeat the row's best instead
    if missing.any():
        cand = np.where(missing, cand[:, :1], cand)
        cand_sim = np.where(missing, cand_sim[:, :1], cand_sim)
    asked = None
    if mutual:
        asked = _searched_back(source, target) if back is None else back.__getitem__
    return FeatureMatches(nearest, best_sim, asked, candidate_rows, cand, feature_distance(cand_sim))


def _searched_back(source: PreparedCloud, target: PreparedCloud) -> Callable[[np.ndarray], np.ndarray]:
    """Target keypoints -> each one's most similar source keypoint, each target searched once
    (FeatureIndex.most_similar) however often it is asked about."""
    best = np.full(len(target.features), -1, dtype=np.int64)

    def back(targets: np.ndarray) -> np.ndarray:
        new = np.unique(targets[best[targets] < 0])
        if len(new):
            best[new] = source.index.most_similar(target.features[new])
        return best[targets]
    return back


def generalized_mutual_matches(similarity: np.ndarray, k: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Generalized mutual matching (GMM): keep (j, l) if l is j's nearest and j is among l's k
    nearest, or j is l's nearest and l among j's k nearest, in each region of (regions, rows,
    cols) similarities. It contains the mutual matches (k = 1) and holds at most rows + cols
    pairs. Ties go to the lower index. (rows, cols: (regions, width), -1 past each region's
    count; count (regions,)), each region's pairs in row-major order, width the most any holds."""
    rows, cols, count = kernels.generalized_mutual_pairs(np.ascontiguousarray(similarity), int(k))
    width = max(int(count.max(initial=0)), 1)
    return rows[:, :width], cols[:, :width], count
