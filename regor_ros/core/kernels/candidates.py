"""Kernels of the initial stage's candidate poses (core/initial.py): how many keypoints each pose
lands on the target's planes, the candidates verified against the features, the most length
agreement among rows."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .common import _smallest
from .consensus import _residual, _rows, _squared_distance
from .threads import JIT


@njit(parallel=True, **JIT)
def landed_counts(rotations, translations, points, planes, threshold2):
    """For each pose h (``rotations`` (H, 3, 3), ``translations`` (H, 3)): how many source
    keypoints (``points`` (N, 3)), moved by it and rounded to float32, land within the squared
    ``threshold2`` of one of their K candidates (``planes``: x, y, z, (3, N, K) float32). Every
    candidate is tested (no early exit), so the loop over them runs in SIMD lanes."""
    poses, rows, k = rotations.shape[0], planes.shape[1], planes.shape[2]
    counts = np.zeros(poses, dtype=np.int64)
    for h in prange(poses):
        R, t = rotations[h], translations[h]
        total = 0
        for i in range(rows):
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            x = np.float32(px * R[0, 0] + py * R[0, 1] + pz * R[0, 2] + t[0])
            y = np.float32(px * R[1, 0] + py * R[1, 1] + pz * R[1, 2] + t[1])
            z = np.float32(px * R[2, 0] + py * R[2, 1] + pz * R[2, 2] + t[2])
            xs, ys, zs = planes[0, i], planes[1, i], planes[2, i]
            hits = 0
            for c in range(k):
                hits += _squared_distance(xs, ys, zs, c, x, y, z) <= threshold2
            total += hits > 0
        counts[h] = total
    return counts


@njit(parallel=True, **JIT)
def verified_candidates(moved, planes, feature_distance, near2, far2):
    """FS-TCD's re-matching of each source keypoint among its K candidates (``planes``: x, y, z
    (3, N, K) float32) under each of a batch of poses (``moved``: the keypoints each pose moves,
    (b, N, 3) float32): (verified: one candidate within the squared ``near2``; the candidate of
    least cost, its feature distance plus 2 when farther than the squared ``far2``, the first on
    ties; that candidate's squared distance), each (b, N). One parallel launch for every pose, not
    one each: beside a busy process each launch waits for its threads to be scheduled."""
    poses, rows, k = moved.shape[0], planes.shape[1], planes.shape[2]
    verified = np.zeros((poses, rows), dtype=np.bool_)
    best = np.zeros((poses, rows), dtype=np.int64)
    residual = np.zeros((poses, rows), dtype=np.float32)
    for i in prange(rows):
        xs, ys, zs = planes[0, i], planes[1, i], planes[2, i]
        e2 = np.empty(k, dtype=np.float32)
        cost = np.empty(k)
        for s in range(poses):
            x, y, z = moved[s, i, 0], moved[s, i, 1], moved[s, i, 2]
            near = 0
            for c in range(k):  # SIMD: no early exit, no running argmin
                e2[c] = _squared_distance(xs, ys, zs, c, x, y, z)
                near += e2[c] <= near2
                cost[c] = np.float64(feature_distance[i, c]) + (2.0 if e2[c] > far2 else 0.0)
            lowest = _smallest(cost)
            c = 0
            while c < k - 1 and cost[c] != lowest:
                c += 1
            verified[s, i], best[s, i], residual[s, i] = near > 0, c, e2[c]
    return verified, best, residual


@njit(parallel=True, **JIT)
def most_length_agreement(source, target, rows, threshold):
    """max over ``rows`` i of #{j : ||a_i - a_j| - |b_i - b_j|| < threshold}: FS-TCD's largest
    set of verified matches agreeing in length with one of them."""
    n = source.shape[0]
    source, target = _rows(source), _rows(target)
    counts = np.zeros(len(rows), dtype=np.int64)
    for m in prange(len(rows)):
        i = rows[m]
        total = 0
        for j in range(n):
            total += _residual(source, target, i, j) < threshold
        counts[m] = total
    return counts.max() if len(rows) else 0
