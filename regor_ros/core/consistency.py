"""Rigid-motion consistency between correspondences.

Two correct correspondences (a_i, b_i), (a_j, b_j) keep their length: |a_i - a_j| = |b_i - b_j|.
Everything that separates inliers from outliers (spectral confidence, second-order consensus,
three-point consistency) is built from that length residual.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels


def _points(points: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(points, dtype=np.float64)


@dataclass
class Compatibility:
    """SC2-PCR's compatibility of n correspondences from their length residual r (rounded to
    float32) and the threshold d: hard r < d and tight r < d / 2 as bit-packed rows
    (n, ceil(n / 64)) uint64; soft max(0, 1 - r^2 / d^2) only where hard is set, as sparse rows
    (row i: columns[starts[i]:starts[i + 1]], ascending, and values[...]). Wrong matches leave most
    pairs incompatible: a dense soft matrix was mostly zeros, and writing it and reading it once per
    power iteration cost more than its products."""

    starts: np.ndarray    # (n + 1,) int64
    columns: np.ndarray   # (hard pairs,) int32
    values: np.ndarray    # (hard pairs,) float32, soft
    hard: np.ndarray      # (n, ceil(n / 64)) uint64
    tight: np.ndarray     # (n, ceil(n / 64)) uint64
    inputs: tuple         # compatibility_matrices' arguments, which seed_consensus takes again


def compatibility(source: np.ndarray, target: np.ndarray, threshold: float,
                  heights: tuple[np.ndarray, float] | None = None) -> Compatibility:
    """The Compatibility of (n, 3) correspondences (source[i], target[i]). ``heights`` (each
    correspondence's height offset along up, and the slack per metre of distance), from a gravity
    prior, is a further condition: two compatible correspondences' offsets agree within d plus
    the slack times their distance."""
    offsets, slack = heights if heights is not None else (np.zeros(len(source)), 0.0)
    inputs = (_points(source), _points(target), float(threshold), np.ascontiguousarray(offsets, dtype=np.float64),
              float(slack), heights is not None)
    starts, columns, values, hard, tight = kernels.compatibility_matrices(*inputs)
    return Compatibility(starts, columns, values, hard, tight, inputs)


def second_order_top_k(compatible: Compatibility, rows: np.ndarray, k: int) -> np.ndarray:
    """For each of ``rows``, the k correspondences of highest SC2-PCR second-order compatibility
    (tight[row] . tight[j]) * hard[row, j], best first, ties in index order: (len(rows), k).
    Counted only where hard is set (bit-packed popcounts), never as a dense product."""
    return kernels.second_order_top_k(compatible.tight, compatible.starts, compatible.columns,
                                      np.asarray(rows, dtype=np.int64), int(k))


def leading_eigenvector(compatible: Compatibility, iterations: int) -> np.ndarray:
    """The soft compatibility's leading eigenvector by power iteration from the all-ones vector,
    stopping early when it has converged (the spectral confidence of SC2-PCR)."""
    return kernels.sparse_leading_eigenvector(compatible.starts, compatible.columns, compatible.values,
                                              int(iterations))


def seed_consensus(first: np.ndarray, compatible: Compatibility, k2: int,
                   iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """SC2-PCR++'s second-stage sets of the seeds' first-stage sets ``first`` (S, k1) and their
    local spectral weights (kernels.seed_consensus): (second (S, k2), weights (S, k2))."""
    return kernels.seed_consensus(first, compatible.hard, *compatible.inputs, int(k2), int(iterations))


def top_k_stable(counts: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k largest integer-valued scores along the last axis, best first, ties in
    index order: what a stable descending argsort gives, without sorting whole rows."""
    n = counts.shape[-1]
    k = min(k, n)
    if k <= 0:
        return np.zeros(counts.shape[:-1] + (0,), dtype=np.int64)
    # the key is exact in float32 (partitions twice as fast) below 2**24
    exact = (max(abs(counts.max()), abs(counts.min())) + 1) * n < 2 ** 24
    key: np.ndarray = counts.astype(np.float32 if exact else np.float64)  # a copy; negated key, smallest first
    key *= -n
    key -= np.arange(n - 1, -1, -1, dtype=key.dtype)
    top = np.argpartition(key, k - 1, axis=-1)[..., :k]
    order = np.argsort(np.take_along_axis(key, top, axis=-1), axis=-1)
    return np.take_along_axis(top, order, axis=-1)


def top_second_order(source: np.ndarray, target: np.ndarray, threshold: float, keep: int) -> np.ndarray:
    """Indices of the ``keep`` correspondences of highest second-order score, best first: the row
    sums of (H H) * H for the hard compatibility H = r < threshold (r in float64), i.e. how many
    pairs agree with both i and j, summed over the j compatible with i. Inliers form a clique
    and score highest."""
    scores = kernels.triangle_scores(_points(source), _points(target), float(threshold), kernels.threads())
    return top_k_stable(scores, keep)
