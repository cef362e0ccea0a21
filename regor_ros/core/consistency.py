"""Rigid-motion consistency between correspondences.

Two correct correspondences (a_i, b_i), (a_j, b_j) keep their length: |a_i - a_j| = |b_i - b_j|.
Everything that separates inliers from outliers (spectral confidence, second-order consensus,
three-point consistency) is built from that length residual.
"""
from __future__ import annotations

import numpy as np

from . import kernels


def _points(points: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(points, dtype=np.float64)


def compatibility(source: np.ndarray, target: np.ndarray, threshold: float,
                  heights: tuple[np.ndarray, float] | None = None):
    """SC2-PCR's three compatibility matrices of (n, 3) correspondences: soft
    max(0, 1 - r^2 / d^2) (n, n) float32, hard r < d (n, n) bool, and tight r < d / 2 with its
    rows bit-packed (n, ceil(n / 64)) uint64, for second_order_top_k; r is the length residual
    rounded to float32. ``heights`` (each correspondence's height offset along up, and the slack
    per metre of distance), from a gravity prior, is a further condition: two compatible
    correspondences' offsets agree within d plus the slack times their distance."""
    offsets, slack = heights if heights is not None else (np.zeros(len(source)), 0.0)
    return kernels.compatibility_matrices(_points(source), _points(target), float(threshold),
                                          np.ascontiguousarray(offsets, dtype=np.float64), float(slack),
                                          heights is not None)


def second_order_top_k(tight: np.ndarray, hard: np.ndarray, rows: np.ndarray, k: int) -> np.ndarray:
    """For each of ``rows``, the k correspondences of highest SC2-PCR second-order compatibility
    (tight[row] . tight[j]) * hard[row, j], best first, ties in index order: (len(rows), k).
    Counted only where hard is set (bit-packed popcounts), never as a dense product."""
    return kernels.second_order_top_k(tight, hard, np.asarray(rows, dtype=np.int64), int(k))


def leading_eigenvector(matrix: np.ndarray, iterations: int) -> np.ndarray:
    """Power iteration from the all-ones vector, batched over leading axes; stops early when every
    vector has converged (the spectral confidence of SC2-PCR)."""
    v = np.ones(matrix.shape[:-1], dtype=matrix.dtype)
    for _ in range(iterations):
        mv = (matrix @ v[..., None])[..., 0]
        mv /= np.linalg.norm(mv, axis=-1, keepdims=True) + 1e-6
        if np.allclose(mv, v, rtol=1e-5, atol=1e-8):
            return mv
        v = mv
    return v


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
    return top_k_stable(kernels.triangle_scores(_points(source), _points(target), float(threshold)), keep)
