"""Kernels of the consensus steps (core/consistency.py, initial.py, regenerate.py, matching.py): the
pairwise compatibility matrices, their leading eigenvector, the seeds' second-order top k, the seeds'
local consensus, mutual feature pairs, triangle scores and a region's agreement."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .common import _flagged
from .threads import JIT


@njit(inline="always")
def _distance(planes, i, j):
    """|p_i - p_j| of points given as x, y, z rows (3, n): summed x, y, z in that order (as
    scipy's cdist does), and contiguous along j, so loops over j run in SIMD lanes."""
    dx = planes[0, i] - planes[0, j]
    dy = planes[1, i] - planes[1, j]
    dz = planes[2, i] - planes[2, j]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(inline="always")
def _residual(source, target, i, j):
    """The length residual of correspondences i and j: ||a_i - a_j| - |b_i - b_j|| (x, y, z rows)."""
    return abs(_distance(source, i, j) - _distance(target, i, j))


@njit(inline="always")
def _rows(points):
    """(n, 3) points as contiguous x, y, z rows (3, n)."""
    return np.ascontiguousarray(points.T)


@njit(inline="always")
def _squared_distance(xs, ys, zs, c, x, y, z):
    """|q_c - p|^2 of candidate c (coordinates in the rows ``xs``, ``ys``, ``zs``) from the point
    (x, y, z), summed x, y, z in that order."""
    dx, dy, dz = xs[c] - x, ys[c] - y, zs[c] - z
    return dx * dx + dy * dy + dz * dz


WORD = 64  # bits of one word of a packed boolean row
_M1, _M2, _M4, _H01 = (np.uint64(0x5555555555555555), np.uint64(0x3333333333333333),
                       np.uint64(0x0F0F0F0F0F0F0F0F), np.uint64(0x0101010101010101))


@njit(inline="always")
def _popcount(x):
    """Set bits of a uint64 (the SWAR count; LLVM emits the popcnt instruction for it)."""
    x = x - ((x >> np.uint64(1)) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return (x * _H01) >> np.uint64(56)


@njit(inline="always")
def _common(bits, i, j):
    """How many columns rows i and j of a packed boolean matrix both have set."""
    total = np.uint64(0)
    for w in range(bits.shape[1]):
        total += _popcount(bits[i, w] & bits[j, w])
    return np.int64(total)


@njit(inline="always")
def _pack_below(values, limit, bits, i):
    """Row i of the packed boolean matrix ``bits`` set to ``values`` < ``limit``, a word at a time."""
    n = len(values)
    for w in range(bits.shape[1]):
        word = np.uint64(0)
        for b in range(min(WORD, n - w * WORD)):
            if values[w * WORD + b] < limit:
                word |= np.uint64(1) << np.uint64(b)
        bits[i, w] = word


@njit(inline="always")
def _compatibility_residual(source, target, heights, threshold, slack, use_heights, i, j):
    """The length residual of correspondences i and j rounded to float32, infinite where their
    ``heights`` differ by more than ``threshold`` + ``slack`` x their source distance (with
    ``use_heights``: the gravity prior)."""
    distance = _distance(source, i, j)
    r = np.float32(abs(distance - _distance(target, i, j)))
    if use_heights and not abs(heights[i] - heights[j]) <= threshold + slack * distance:
        r = np.float32(np.inf)
    return r


@njit(inline="always")
def _soft(source, target, heights, threshold, slack, use_heights, d2, i, j):
    """The soft compatibility max(0, 1 - r^2 / d^2) of correspondences i and j (d^2 = ``d2``)."""
    r = _compatibility_residual(source, target, heights, threshold, slack, use_heights, i, j)
    value = np.float32(1.0) - (r * r) / d2
    return value if value > 0 else np.float32(0.0)


@njit(inline="always")
def _set_columns(bits, i, first, out):
    """The set columns of row i of a packed boolean matrix from column ``first`` on, ascending,
    into ``out``; how many. A word's set bits are taken lowest first (the lowest's position is the
    count of the bits below it), so a sparse row costs its set bits, not its width."""
    count = 0
    for w in range(first // WORD, bits.shape[1]):
        word = bits[i, w]
        if w == first // WORD:
            word &= ~((np.uint64(1) << np.uint64(first % WORD)) - np.uint64(1))
        while word:
            out[count] = w * WORD + np.int64(_popcount((word & (~word + np.uint64(1))) - np.uint64(1)))
            word &= word - np.uint64(1)
            count += 1
    return count


@njit(parallel=True, **JIT)
def compatibility_matrices(source, target, threshold, heights, slack, use_heights):
    """SC2-PCR's compatibility of (n, 3) correspondences from the length residual
    r = ||a_i - a_j| - |b_i - b_j|| rounded to float32: hard = r < d and tight = r < d / 2 as
    bit-packed rows (n, ceil(n / 64)) uint64, and soft = max(0, 1 - r^2 / d^2) where hard is set,
    as sparse rows (row i: columns[starts[i]:starts[i + 1]], ascending, and their values). With
    ``use_heights``, a pair whose ``heights`` differ by more than ``threshold`` + ``slack`` x its
    source distance is incompatible in all three (the gravity prior). (starts, columns, values,
    hard, tight)"""
    n = source.shape[0]
    words = (n + WORD - 1) // WORD
    hard = np.zeros((n, words), dtype=np.uint64)
    tight = np.zeros((n, words), dtype=np.uint64)
    counts = np.zeros(n, dtype=np.int64)
    d = np.float32(threshold)
    half = np.float32(threshold / 2)
    d2 = np.float32(threshold ** 2)
    source, target = _rows(source), _rows(target)
    for i in prange(n):
        # the row's residuals first (SIMD), then the packed rows from them
        r = np.empty(n, dtype=np.float32)
        for j in range(n):
            r[j] = _compatibility_residual(source, target, heights, threshold, slack, use_heights, i, j)
        _pack_below(r, d, hard, i)
        _pack_below(r, half, tight, i)
        for w in range(words):
            counts[i] += _popcount(hard[i, w])
    starts = np.zeros(n + 1, dtype=np.int64)
    starts[1:] = np.cumsum(counts)
    columns = np.empty(starts[n], dtype=np.int32)
    values = np.empty(starts[n], dtype=np.float32)
    for i in prange(n):  # the residuals again, of the compatible pairs only
        _set_columns(hard, i, 0, columns[starts[i]:starts[i + 1]])
        for at in range(starts[i], starts[i + 1]):
            values[at] = _soft(source, target, heights, threshold, slack, use_heights, d2, i, columns[at])
    return starts, columns, values, hard, tight


@njit(inline="always")
def _sparse_row_product(starts, columns, values, i, v):
    """Row i of a matrix given as sparse rows times the vector v, in float64: four running sums
    (every fourth entry each), so that the adds do not wait on one another."""
    s0 = s1 = s2 = s3 = 0.0
    a, end = starts[i], starts[i + 1]
    while a + 4 <= end:
        s0 += np.float64(values[a]) * v[columns[a]]
        s1 += np.float64(values[a + 1]) * v[columns[a + 1]]
        s2 += np.float64(values[a + 2]) * v[columns[a + 2]]
        s3 += np.float64(values[a + 3]) * v[columns[a + 3]]
        a += 4
    while a < end:
        s0 += np.float64(values[a]) * v[columns[a]]
        a += 1
    return np.float32((s0 + s1) + (s2 + s3))


@njit(parallel=True, **JIT)
def sparse_leading_eigenvector(starts, columns, values, iterations):
    """The leading eigenvector of a symmetric matrix given as sparse rows (compatibility_matrices'
    soft), by power iteration from the all-ones vector (float32, each row's sum in float64 in
    column order); stops at the first step where no entry moves by more than 1e-8 + 1e-5 of
    itself (numpy's allclose)."""
    n = len(starts) - 1
    v = np.ones(n, dtype=np.float32)
    mv = np.empty(n, dtype=np.float32)
    for _ in range(iterations):
        for i in prange(n):
            mv[i] = _sparse_row_product(starts, columns, values, i, v)
        norm = np.float32(np.sqrt(np.sum(mv.astype(np.float64) ** 2))) + np.float32(1e-6)
        mv /= norm
        settled = True
        for i in range(n):
            if not abs(mv[i] - v[i]) <= 1e-8 + 1e-5 * abs(v[i]):
                settled = False
                break
        v, mv = mv, v
        if settled:
            break
    return v


@njit(inline="always")
def _top_k_into(values, k, out):
    """The indices of the k largest ``values`` into ``out``, best first; ties go to the lower index."""
    best = np.empty(k, dtype=values.dtype)
    filled = 0
    for j in range(len(values)):
        v = values[j]
        if filled == k and not v > best[k - 1]:
            continue
        p = min(filled, k - 1)
        while p > 0 and v > best[p - 1]:
            best[p], out[p] = best[p - 1], out[p - 1]
            p -= 1
        best[p], out[p] = v, j
        filled = min(filled + 1, k)


@njit(inline="always")
def _top_k_of_row(values, columns, k, n, out):
    """The k best columns of a row, into ``out``: its nonzero ``values`` sit at ``columns``
    (ascending) and every other column is 0; by value, ties and zeros in column order. A
    selection of the k, not a sort of the row (a seed's row holds hundreds of columns, k is 20)."""
    best = np.empty(k, dtype=np.int64)
    ranked = min(k, len(values))
    if ranked > 0:
        _top_k_into(values, ranked, best)
    filled = 0
    for m in range(ranked):
        if values[best[m]] <= 0:
            break
        out[filled] = columns[best[m]]
        filled += 1
    if filled < k:  # then the zero-valued columns, lowest first
        taken = np.zeros(n, dtype=np.bool_)
        for m in range(filled):
            taken[out[m]] = True
        for column in range(n):
            if filled == k:
                break
            if not taken[column]:
                out[filled] = column
                filled += 1


@njit(parallel=True, **JIT)
def second_order_top_k(tight, starts, columns_of, rows, k):
    """For each of ``rows``: the k columns j of highest second-order compatibility
    (tight[row] . tight[j]) x hard[row, j], best first, ties in column order (``tight``
    bit-packed; the hard-compatible columns of row i are columns_of[starts[i]:starts[i + 1]],
    ascending, compatibility_matrices' sparse rows). Only those are counted (the others are 0)."""
    n = tight.shape[0]
    out = np.empty((len(rows), k), dtype=np.int64)
    for s in prange(len(rows)):
        row = rows[s]
        columns = columns_of[starts[row]:starts[row + 1]]
        values = np.empty(len(columns), dtype=np.int64)
        for m in range(len(columns)):
            values[m] = _common(tight, row, columns[m])
        _top_k_of_row(values, columns, k, n, out[s])
    return out


@njit(parallel=True, **JIT)
def seed_consensus(first, hard, source, target, threshold, heights, slack, use_heights, k2, iterations):
    """SC2-PCR++'s second stage and local spectral weights for each seed's first-stage set
    ``first`` (S, k1), best member first: the k2 members most hard-compatible through the set with
    both the best member and themselves (counts, ties to the earlier member), then the leading
    eigenvector of their soft compatibility without its diagonal, by power iteration from ones
    (float32, stopping for the whole batch at the first step where every seed's vector has
    settled, as SC2-PCR's batched iteration does). ``hard`` bit-packed as compatibility_matrices
    gives it, from the same correspondences and arguments, with which the few soft values a set
    needs are computed again (faster than looking them up in the sparse rows).
    (second (S, k2), weights (S, k2))."""
    seeds, k1 = first.shape
    source, target = _rows(source), _rows(target)
    d2 = np.float32(threshold ** 2)
    second = np.empty((seeds, k2), np.int64)
    vectors = np.ones((seeds, iterations + 1, k2), np.float32)   # [s, 0]: the start
    settled = np.zeros((seeds, iterations), np.bool_)
    scores = np.zeros((seeds, k1), np.int64)          # scratch rows: nothing allocated per seed
    tops = np.empty((seeds, k2), np.int64)
    local = np.empty((seeds, k2, k2), np.float32)
    for s in prange(seeds):
        members = first[s]
        for m in range(k1):
            if _flagged(hard[members[0]], members[m]):
                for j in range(k1):
                    if _flagged(hard[members[m]], members[j]):
                        scores[s, j] += 1
        _top_k_into(scores[s], k2, tops[s])
        for i in range(k2):
            second[s, i] = members[tops[s, i]]
        for i in range(k2):
            for j in range(k2):
                local[s, i, j] = _soft(source, target, heights, threshold, slack, use_heights, d2, second[s, i],
                                       second[s, j]) if i != j else np.float32(0.0)
        for step in range(iterations):
            v, mv = vectors[s, step], vectors[s, step + 1]
            total = np.float32(0.0)
            for i in range(k2):
                mv[i] = np.float32(0.0)
                for j in range(k2):
                    mv[i] += local[s, i, j] * v[j]
                total += mv[i] * mv[i]
            norm = np.float32(np.sqrt(total) + np.float32(1e-6))
            close = True
            for i in range(k2):
                mv[i] /= norm
                close = close and abs(mv[i] - v[i]) <= 1e-8 + 1e-5 * abs(v[i])
            settled[s, step] = close
    stop = iterations
    for step in range(iterations):
        if settled[:, step].all():
            stop = step + 1
            break
    return second, vectors[:, stop].copy()


@njit(parallel=True, **JIT)
def generalized_mutual_pairs(similarity, k):
    """Generalized mutual matching over batched (regions, rows, cols) similarities: (r, c) is kept
    when c is r's best and r among c's k best, or r is c's best and c among r's k best. Ties go
    to the lower index (a partition leaves them to its implementation). Each region's pairs in
    row-major order: (rows (regions, rows + cols), cols (the same), count (regions,)), -1 past
    a region's count (a region holds at most rows + cols pairs)."""
    regions, n_rows, n_cols = similarity.shape
    k_row, k_col = min(k, n_cols), min(k, n_rows)
    pair_rows = np.full((regions, n_rows + n_cols), -1, np.int64)
    pair_cols = np.full((regions, n_rows + n_cols), -1, np.int64)
    count = np.zeros(regions, np.int64)
    for s in prange(regions):
        mask = np.zeros((n_rows, n_cols), dtype=np.bool_)
        row_top = np.empty((n_rows, k_row), dtype=np.int64)
        col_top = np.empty((n_cols, k_col), dtype=np.int64)
        for r in range(n_rows):
            _top_k_into(similarity[s, r], k_row, row_top[r])
        columns = np.ascontiguousarray(similarity[s].T)
        for c in range(n_cols):
            _top_k_into(columns[c], k_col, col_top[c])
        for r in range(n_rows):
            c = row_top[r, 0]
            for m in range(k_col):
                if col_top[c, m] == r:
                    mask[r, c] = True
        for c in range(n_cols):
            r = col_top[c, 0]
            for m in range(k_row):
                if row_top[r, m] == c:
                    mask[r, c] = True
        kept = 0
        for r in range(n_rows):
            for c in range(n_cols):
                if mask[r, c]:
                    pair_rows[s, kept], pair_cols[s, kept] = r, c
                    kept += 1
        count[s] = kept
    return pair_rows, pair_cols, count


@njit(parallel=True, **JIT)
def triangle_scores(source, target, threshold, runs):
    """Row sums of the second-order compatibility (H H) * H of the hard compatibility
    H = (length residual < threshold, in float64): for each i, the pairs (j, l) with i, j, l
    mutually compatible, counted over j. ``runs``: the threads the pairs are counted on."""
    n = source.shape[0]
    source, target = _rows(source), _rows(target)
    bits = np.zeros((n, (n + WORD - 1) // WORD), dtype=np.uint64)
    for i in prange(n):
        r = np.empty(n)
        for j in range(n):
            r[j] = _residual(source, target, i, j)
        _pack_below(r, threshold, bits, i)
    # common(i, j) = common(j, i): each pair counted once (j > i) and added to both rows, in one
    # row of counts per run of rows (every runs-th row, to balance the triangle); integer sums,
    # the same whatever the runs
    partial = np.zeros((runs, n), dtype=np.int64)
    for run in prange(runs):
        beyond = np.empty(n, dtype=np.int64)
        for i in range(run, n, runs):
            total = _common(bits, i, i)
            for m in range(_set_columns(bits, i, i + 1, beyond)):
                both = _common(bits, i, beyond[m])
                total += both
                partial[run, beyond[m]] += both
            partial[run, i] += total
    return partial.sum(axis=0)


@njit(parallel=True, **JIT)
def region_agreement(source, target, valid, threshold):
    """For each valid slot j of each region (``source``, ``target``: (regions, slots, 3) matched
    points; ``valid``: (regions, slots)): how many valid slots l of its region agree with it in
    length, ||a_j - a_l| - |b_j - b_l|| < ``threshold`` (l = j included). 0 for invalid slots."""
    regions, slots = valid.shape
    counts = np.zeros((regions, slots), dtype=np.int64)
    for g in prange(regions):
        a, b = _rows(source[g]), _rows(target[g])
        for j in range(slots):
            if valid[g, j]:
                total = 0
                for m in range(slots):
                    total += valid[g, m] and _residual(a, b, j, m) < threshold
                counts[g, j] = total
    return counts
