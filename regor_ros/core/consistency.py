"""Rigid-motion consistency between correspondences.

Two correct correspondences (a_i, b_i), (a_j, b_j) keep their length: |a_i - a_j| = |b_i - b_j|.
Everything that separates inliers from outliers (spectral confidence, second-order consensus,
three-point consistency) is built from that length residual.
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np
from scipy import sparse
from scipy.spatial.distance import cdist


def pairwise_distances(points: np.ndarray) -> np.ndarray:
    """Euclidean distance matrices of batched (..., n, 3) points by direct differences (the Gram
    trick loses centimetres on raw LiDAR coordinates)."""
    planes = np.moveaxis(points, -1, 0)
    return np.sqrt(sum((x[..., :, None] - x[..., None, :]) ** 2 for x in planes))


RESIDUAL_ROWS = 256  # rows of the length residual computed at once: stays in cache, twice as fast
# below this fraction of set entries a sparse product is faster (measured: LiDAR's ~0.2 %, ten
# times faster; RGB-D fragments' ~5 %, twice slower)
SPARSE_DENSITY = 0.01


def length_residual(source: np.ndarray, target: np.ndarray, dtype=np.float64) -> np.ndarray:
    """|(|a_i - a_j|) - (|b_i - b_j|)| for every pair of correspondences (batched over leading
    axes), computed in float64 and stored as ``dtype``."""
    if source.ndim > 2:
        return np.abs(pairwise_distances(source) - pairwise_distances(target)).astype(dtype, copy=False)
    out = np.empty((len(source), len(source)), dtype=dtype)
    for rows, block, _ in _residual_blocks(source, target):
        out[rows] = block
    return out


def _residual_blocks(source: np.ndarray, target: np.ndarray):
    """The length residual of (n, 3) correspondences, RESIDUAL_ROWS rows at a time (float64),
    with the source distances it came from."""
    for start in range(0, len(source), RESIDUAL_ROWS):
        rows = slice(start, start + RESIDUAL_ROWS)
        distance = cdist(source[rows], source)
        yield rows, np.abs(distance - cdist(target[rows], target)), distance


def compatibility(source: np.ndarray, target: np.ndarray, threshold: float,
                  also: Optional[Callable[[slice, np.ndarray], np.ndarray]] = None):
    """SC2-PCR's three compatibility matrices of (n, 3) correspondences, (n, n) float32: soft
    max(0, 1 - r^2 / d^2), hard r < d and tight r < d / 2 of the length residual r (stored as
    float32). Built block by block while each residual block is in cache, never storing r.
    ``tight`` comes back as a sparse matrix when at most SPARSE_DENSITY of it is set. ``also``
    ((rows, their source distances) -> (len(rows), n) bool) is a further condition two compatible correspondences must
    meet (a gravity prior's height agreement)."""
    n = len(source)
    soft, hard, tight = (np.empty((n, n), dtype=np.float32) for _ in range(3))
    nonzero = []  # tight's entries, block by block, while it stays sparse
    for rows, block, distance in _residual_blocks(source, target):
        r = block.astype(np.float32)
        if also is not None:
            r[~also(rows, distance)] = np.inf
        np.less(r, threshold, out=hard[rows])
        near = r < threshold / 2
        tight[rows] = near
        if nonzero is not None and np.count_nonzero(near) <= SPARSE_DENSITY * near.size:
            nonzero.append(np.nonzero(near))
        else:
            nonzero = None
        r **= 2
        r /= threshold ** 2
        np.subtract(1.0, r, out=r)
        np.maximum(0.0, r, out=soft[rows])
    if nonzero:
        row = np.concatenate([i + start for start, (i, _) in zip(range(0, n, RESIDUAL_ROWS), nonzero)])
        col = np.concatenate([j for _, j in nonzero])
        tight = sparse.csr_matrix((np.ones(len(row), np.float32), (row, col)), shape=(n, n))
    return soft, hard, tight


def second_order(tight, hard: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """SC2-PCR's second-order compatibility of ``rows``: (tight[rows] @ tight) * hard[rows],
    (len(rows), n) float32 holding exact counts; ``tight`` dense or sparse (the same result)."""
    product = tight[rows] @ tight
    product = product.toarray() if sparse.issparse(product) else product
    product *= hard[rows]
    return product


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


def second_order_scores(hard: np.ndarray) -> np.ndarray:
    """Row sums of the second-order compatibility (H H) * H: how many pairs agree with both i and j,
    summed over the j compatible with i. Inliers form a clique and score highest."""
    return ((hard @ hard) * hard).sum(axis=-1)


def top_k_stable(counts: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k largest integer-valued scores along the last axis, best first, ties in
    index order: what a stable descending argsort gives, without sorting whole rows."""
    n = counts.shape[-1]
    k = min(k, n)
    if k <= 0:
        return np.zeros(counts.shape[:-1] + (0,), dtype=np.int64)
    # the key is exact in float32 (partitions twice as fast) below 2**24
    exact = (max(abs(counts.max()), abs(counts.min())) + 1) * n < 2 ** 24
    key = counts.astype(np.float32 if exact else np.float64)  # a copy; negated key, smallest first
    key *= -n
    key -= np.arange(n - 1, -1, -1, dtype=key.dtype)
    top = np.argpartition(key, k - 1, axis=-1)[..., :k]
    order = np.argsort(np.take_along_axis(key, top, axis=-1), axis=-1)
    return np.take_along_axis(top, order, axis=-1)


def top_second_order(hard: np.ndarray, keep: int) -> np.ndarray:
    """Indices of the ``keep`` rows with the highest second-order score, best first."""
    return top_k_stable(second_order_scores(hard), keep)
