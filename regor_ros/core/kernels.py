"""Compiled inner loops of the consensus steps, the refinements, the free-space check, the feature
search and FPFH (numba), where numpy did the arithmetic in a wider form than the method needs, FAISS read
memory in an order that made it wait or searched the same products more than once, or Open3D
searched a kd-tree per point holding the GIL.

Each consensus kernel gives exactly what the numpy expression it replaced gave (the tests hold
them to those expressions): the same float32 rounding of the length residual, integer counts, ties
broken by index; the seeds' local spectral weights and the refinement's moments are the same sums
in another order (the last bits differ). The feature search gives the similarities of a numpy matrix product; FAISS,
which it replaced, sums in another order (the last bit may differ). Nothing depends on the
number of threads. FPFH gives Open3D's histograms (the tests hold it to them) but for the order
of a sum's terms and which of the neighbours tied at the max_nn-th distance are kept; the normals
are Open3D's to the bit, its arithmetic step for step (features.surface_normals asks Open3D's
kd-tree for the order of tied neighbours where it matters).
Compiled code is cached on disk (``cache=True``); ``warm_up`` compiles or loads every kernel, so a
node pays that when it starts, not on its first relocalization. The threads they run on are
this module's too: OpenMP first, and numpy's BLAS kept off the cores while a registration runs
(``blas_on_one_thread``).
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from functools import lru_cache

import numba
import numpy as np
from numba import njit, prange
from threadpoolctl import ThreadpoolController

JIT = dict(cache=True, nogil=True)
# OpenMP first: thread-safe (the node registers off its executor thread), and never the warning a
# too-old TBB (some pip environments carry one) prints when tried first
numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


@lru_cache(maxsize=1)
def _numpy_blas() -> ThreadpoolController:
    """The BLAS libraries loaded (numpy's, scipy's), except the copy FAISS carries: FAISS finds
    the cells a map query probes, and on one thread it was slower."""
    blas = ThreadpoolController().select(user_api="blas")
    return blas.select(filepath=[lib.filepath for lib in blas.lib_controllers if "faiss" not in lib.filepath.lower()])


_blas_lock = threading.Lock()
_blas_users = 0
_blas_limit = None


@contextmanager
def blas_on_one_thread():
    """numpy's BLAS on one thread while registrations run (the first in limits, the last out
    restores). After a call OpenBLAS keeps its worker threads spinning, waiting for the next; on
    two cores they took a core from the compiled kernels and FAISS that came next, and a
    registration's products are too small
    to gain from a second thread."""
    global _blas_users, _blas_limit
    with _blas_lock:
        if _blas_users == 0:
            _blas_limit = _numpy_blas().limit(limits=1)
        _blas_users += 1
    try:
        yield
    finally:
        with _blas_lock:
            _blas_users -= 1
            if _blas_users == 0:
                _blas_limit.restore_original_limits()


def threads() -> int:
    """The threads a registration's parallel work runs on (the kernels' own; ``regor-batch``
    gives each worker its share)."""
    return numba.get_num_threads()


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
def _kth_smallest(values, n, k):
    """The k-th smallest (1-based) of values[:n], which it reorders so that the k smallest come
    first: Hoare's selection in place (np.partition allocates a copy on every call, and the
    kernels select per point, per query and per list)."""
    lo, hi, target = 0, n - 1, k - 1
    while lo < hi:
        pivot = values[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if target <= j:
            hi = j
        elif target >= i:
            lo = i
        else:
            break
    return values[target]


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


@njit(fastmath={"nnan", "nsz"}, inline="always")
def _smallest(values):
    """The least of finite ``values``: exact in any order, so the reduction may run in SIMD lanes."""
    least = np.inf
    for v in values:
        least = min(least, v)
    return least


@njit(fastmath={"nnan", "nsz"}, inline="always")
def _largest(values):
    """The greatest of finite ``values``: exact in any order, so the reduction may run in SIMD lanes."""
    greatest = -np.inf
    for v in values:
        greatest = max(greatest, v)
    return greatest


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


@njit(inline="always")
def _bin(x, y, z, r, step, cols):
    """Flat (elevation, azimuth) bin of a direction (x, y, z) at range r."""
    elevation = np.arcsin(min(max(z / r, -1.0), 1.0)) + np.pi / 2
    azimuth = np.arctan2(y, x) + np.pi
    return np.int64(np.floor(elevation / step)) * cols + np.int64(np.floor(azimuth / step)) % cols


@njit(parallel=True, **JIT)
def spherical_bins(offsets, step, cols, min_range):
    """Range and flat (elevation, azimuth) bin of each point given relative to a viewpoint, for
    the points farther than ``min_range`` (in order): what a range image is built from."""
    n = offsets.shape[0]
    ranges = np.empty(n)
    index = np.empty(n, dtype=np.int64)
    for i in prange(n):
        x, y, z = offsets[i, 0], offsets[i, 1], offsets[i, 2]
        ranges[i] = np.sqrt(x * x + y * y + z * z)
        if ranges[i] > min_range:
            index[i] = _bin(x, y, z, ranges[i], step, cols)
    keep = ranges > min_range
    return ranges[keep], index[keep]


@njit(parallel=True, **JIT)
def free_space_classes(points, viewpoint, free_depth, step, min_range, margin, margin_ratio, slack):
    """Per point: (lands on a bin of the range image ``free_depth`` (float32, 0 = unknown) seen
    from ``viewpoint``, lies nearer than that bin's free depth less ``margin``, ``margin_ratio``
    of the depth (both in float32, as the depth) and its ``slack``)."""
    n, cols = points.shape[0], free_depth.shape[1]
    flat = free_depth.ravel()
    seen = np.zeros(n, dtype=np.bool_)
    inside = np.zeros(n, dtype=np.bool_)
    near, ratio = np.float32(margin), np.float32(margin_ratio)
    for i in prange(n):
        x, y, z = points[i, 0] - viewpoint[0], points[i, 1] - viewpoint[1], points[i, 2] - viewpoint[2]
        r = np.sqrt(x * x + y * y + z * z)
        if r > min_range:
            depth = flat[_bin(x, y, z, r, step, cols)]
            if depth > 0:
                seen[i] = True
                inside[i] = r < np.float64(depth - near - ratio * depth) - slack[i]
    return seen, inside


@njit(**JIT)
def splatted_free_depth(index, ranges, width, rows, cols, blur):
    """A range image's free depth (rows, cols) from its returns: each return (flat bin ``index``,
    float32 ``ranges``) covers the bins fewer than ``width`` bins from its own, and is read as
    free depth out to ``width`` + ``blur`` bins (the nearest return counts); azimuth wraps around,
    elevation stops at the poles. A bin no return covers is unknown (0). The same image as a
    minimum and a maximum filter per footprint width, written once per return instead of once per
    width."""
    free = np.full((rows, cols), np.inf, dtype=np.float32)
    covered = np.zeros((rows, cols), dtype=np.bool_)
    for i in range(len(index)):
        row, col, w, depth = index[i] // cols, index[i] % cols, width[i], ranges[i]
        reach = w + blur
        for r in range(max(row - reach, 0), min(row + reach, rows - 1) + 1):
            near_row = abs(r - row) < w
            for step in range(-reach, reach + 1):
                c = (col + step) % cols
                if depth < free[r, c]:
                    free[r, c] = depth
                if near_row and abs(step) < w:
                    covered[r, c] = True
    for r in range(rows):
        for c in range(cols):
            if not covered[r, c]:
                free[r, c] = 0.0
    return free


@njit(inline="always")
def _row_at(rows, a, b, c):
    """The position of row (a, b, c) in ``rows`` (lexicographically sorted, unique), -1 if absent."""
    lo, hi = 0, len(rows)
    while lo < hi:
        mid = (lo + hi) // 2
        r = rows[mid]
        if r[0] < a or (r[0] == a and (r[1] < b or (r[1] == b and r[2] < c))):
            lo = mid + 1
        else:
            hi = mid
    if lo < len(rows) and rows[lo, 0] == a and rows[lo, 1] == b and rows[lo, 2] == c:
        return lo
    return -1


@njit(**JIT)
def greedy_apart(points, cells, visit, radius):
    """gate/evidence.independent's greedy rule on one point per cell of the radius: ``points``
    and their ``cells`` (lexicographically sorted, unique), taken in the order ``visit``; each
    point not yet within ``radius`` of a kept one is kept, and every point within it of that one
    is taken (squared distances summed x, y, z, as scipy's ball query). Another point of a cell's
    27 neighbours is the only one that can be that near. Which points are kept (bool)."""
    n = len(points)
    kept = np.zeros(n, np.bool_)
    taken = np.zeros(n, np.bool_)
    limit = radius * radius
    for i in visit:
        if taken[i]:
            continue
        kept[i] = True
        for a in range(cells[i, 0] - 1, cells[i, 0] + 2):
            for b in range(cells[i, 1] - 1, cells[i, 1] + 2):
                for c in range(cells[i, 2] - 1, cells[i, 2] + 2):
                    j = _row_at(cells, a, b, c)
                    if j < 0:
                        continue
                    dx, dy, dz = points[j, 0] - points[i, 0], points[j, 1] - points[i, 1], points[j, 2] - points[i, 2]
                    if dx * dx + dy * dy + dz * dz <= limit:
                        taken[j] = True
    return kept


@njit(parallel=True, **JIT)
def within_any(points, centres, radii):
    """Mask of the points within ``radii[k]`` of some ``centres[k]`` (squared distances summed x,
    y, z, as scipy's ball query): the part of a large cloud a sensor could have seen, without a
    tree query's Python lists (a map's 100 k indices cost milliseconds to gather)."""
    n = points.shape[0]
    inside = np.zeros(n, dtype=np.bool_)
    limits = radii * radii
    for i in prange(n):
        for k in range(len(centres)):
            dx, dy, dz = points[i, 0] - centres[k, 0], points[i, 1] - centres[k, 1], points[i, 2] - centres[k, 2]
            if dx * dx + dy * dy + dz * dz <= limits[k]:
                inside[i] = True
                break
    return inside


# --- the inverted file's by-cell scan (feature_index.CellTable) ---

_LOW = np.uint64(0xFFFFFFFF)
_SIGN = np.uint32(0x80000000)
_EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)


@njit
def _rank_key(similarity, position):
    """One unsigned integer that orders (similarity, position) as a top-k list does: smaller
    is better, more similar first, ties to the lower position (float32 bits made monotone)."""
    bits = np.float32(similarity).view(np.uint32)
    ascending = np.uint32(~bits) if bits & _SIGN else np.uint32(bits | _SIGN)
    return (np.uint64(np.uint32(~ascending)) << np.uint64(32)) | np.uint64(position)


@njit
def _similarity_of(key):
    """The similarity a key ranks; -inf for an empty slot."""
    if key == _EMPTY:
        return np.float32(-np.inf)
    ascending = np.uint32(~np.uint32(key >> np.uint64(32)))
    bits = ascending & np.uint32(~_SIGN) if ascending & _SIGN else ~ascending
    return np.uint32(bits).view(np.float32)


@njit
def _position_of(key):
    """The position a key ranks; -1 for an empty slot."""
    return np.int64(-1) if key == _EMPTY else np.int64(key & _LOW)


@njit
def _replace_worst(heap, key):
    """Put ``key`` in place of the worst (largest) key of a max-heap of keys."""
    k = len(heap)
    i = 0
    while True:
        child = 2 * i + 1
        if child >= k:
            break
        if child + 1 < k and heap[child + 1] > heap[child]:
            child += 1
        if heap[child] <= key:
            break
        heap[i] = heap[child]
        i = child
    heap[i] = key


@njit(inline="always")
def _offer_to_heap(heap, dots, start, floor):
    """Offer a run of similarities (positions start, start + 1, ...) to a top-k heap of keys: one
    array of k per query, which suits a scan that visits the queries' lists in scattered order,
    a few hundred similarities at a time (a buffered list's floor, count and spare room were
    slower there). Only a similarity above ``floor`` is taken. Positions ascend within a run and
    across the runs offered, so an equal one is never better."""
    bar = max(_similarity_of(heap[0]), floor)
    for j in range(len(dots)):
        if dots[j] > bar:
            _replace_worst(heap, _rank_key(dots[j], start + j))
            bar = max(_similarity_of(heap[0]), floor)


@njit(inline="always")
def _spare(k):
    """A top-k list's room beyond its k: each time it fills, the k best are kept and the floor
    rises, so this many entries pass between two selections."""
    return 2 * k + 16


@njit
def _keep_best(keys, k):
    """Keep the k best (smallest) of a full list of ``keys`` in its first k places (selected in
    place), empty the rest; the similarity of the worst kept (the list's new floor)."""
    worst = _kth_smallest(keys, len(keys), k)
    keys[k:] = _EMPTY
    return _similarity_of(worst)


@njit(inline="always")
def _offer_to_list(keys, held, floor, i, k, dots, start, passed):
    """Offer a run of similarities (positions start, start + 1, ...) to top-k list ``i``: its
    rank ``keys`` (k + _spare(k) places, ``held`` of them filled) take every similarity above its
    ``floor``; a full list keeps its k best and raises the floor to the worst of them (FAISS's
    reservoir). Started at a sampled floor (flat_search), a list takes about 3k entries where a
    heap re-orders itself on nine times k. The run's few above the floor are first picked out
    without a branch (into ``passed``, room for the run), which a branch per similarity, taken
    at random, mispredicted.
    Positions ascend within a run and across the runs offered, so a similarity equal to the
    floor is never better than the k kept."""
    bar, filled = floor[i], held[i]
    above = 0
    for j in range(len(dots)):
        passed[above] = j
        above += dots[j] > bar
    for a in range(above):
        j = passed[a]
        if dots[j] > bar:
            if filled == len(keys):
                bar, filled = _keep_best(keys, k), k
                if not dots[j] > bar:
                    continue
            keys[filled] = _rank_key(dots[j], start + j)
            filled += 1
    floor[i], held[i] = bar, filled


@njit(inline="always")
def _unpack_best(keys, positions, similarities):
    """The len(positions) best of ``keys`` (any order; reordered), most similar first, into the
    two rows: selected and sorted in place."""
    k = len(positions)
    if 0 < k < len(keys):
        _kth_smallest(keys, len(keys), k)
    ranked = keys[:k]
    ranked.sort()
    for i in range(len(positions)):
        similarities[i] = _similarity_of(ranked[i])
        positions[i] = _position_of(ranked[i])


@njit(parallel=True, **JIT)
def cell_top_k(queries, probed, table, bounds, k, chunks):
    """The k most similar table rows of each query among its probed cells: (positions (Q, k),
    -1 where fewer were found; similarities (Q, k), -inf there), most similar first, ties to the
    lower position. ``table`` (M, D) holds the features cell by cell (cell c in rows
    bounds[c]:bounds[c + 1]); ``probed`` (Q, P) the cells each query scans.

    The loop runs by cell: each cell's rows are read once, in one matrix product (BLAS) with all
    the queries that probe it, where a query-by-query scan streams every probed cell from memory
    per query. The cells are split into ``chunks`` runs of about equal work, each keeping its own
    top k per query; the runs are merged in the list's order, so the result does not depend on
    ``chunks`` (the thread count). Keeping the heaps is most of the scan's work, so a first pass
    over every FLOOR_STRIDE-th row of each cell sets each query a floor (``_sampled_floor``: about
    its 3k-th best), and a heap takes only what is above it; a query left with fewer than k above
    its floor is scanned again without one, from the same products (``_cell_pass``)."""
    n_queries, n_probed = probed.shape
    cells = len(bounds) - 1
    rows = bounds[1:] - bounds[:-1]
    sampled_rows = (rows + FLOOR_STRIDE - 1) // FLOOR_STRIDE
    # the (query, cell) pairs grouped by cell, queries ascending (a counting sort), and where each
    # pair's sampled similarities go in its query's run of them
    asking_start = np.zeros(cells + 1, np.int64)
    samples = np.zeros(n_queries + 1, np.int64)
    for q in range(n_queries):
        for p in range(n_probed):
            asking_start[probed[q, p] + 1] += 1
            samples[q + 1] += sampled_rows[probed[q, p]]
    asking_start = np.cumsum(asking_start)
    samples = np.cumsum(samples)
    filled = asking_start[:-1].copy()
    asking = np.empty(n_queries * n_probed, np.int64)
    sample_at = np.empty(n_queries * n_probed, np.int64)
    for q in range(n_queries):
        at = samples[q]
        for p in range(n_probed):
            c = probed[q, p]
            asking[filled[c]] = q
            sample_at[filled[c]] = at
            at += sampled_rows[c]
            filled[c] += 1
    work = np.cumsum((asking_start[1:] - asking_start[:-1]) * (rows + 8))
    first = np.full(chunks + 1, cells, np.int64)
    first[0] = 0
    if cells:
        first[1:chunks] = np.searchsorted(work, work[-1] * np.arange(1, chunks) / chunks)
    floor = np.full(n_queries, -np.inf, np.float32)
    if 3 * k > FLOOR_STRIDE:    # a floor from one sampled similarity would be one of the k itself
        _sampled_floors(queries, table, bounds, asking, asking_start, first, sample_at, samples, sampled_rows,
                        k, chunks, floor)
    heaps = _cell_pass(queries, table, bounds, asking, asking_start, first, floor,
                       np.ones(n_queries, np.bool_), k, chunks)
    short = np.zeros(n_queries, np.bool_)
    for q in prange(n_queries):
        kept = 0
        for t in range(chunks):
            for j in range(k):
                kept += heaps[t, q, j] != _EMPTY
        short[q] = kept < k and floor[q] > -np.inf
    if short.any():
        unfloored = np.full(n_queries, -np.inf, np.float32)
        again = _cell_pass(queries, table, bounds, asking, asking_start, first, unfloored, short, k, chunks)
        for q in range(n_queries):
            if short[q]:
                heaps[:, q] = again[:, q]
    out_position = np.empty((n_queries, k), np.int64)
    out_similarity = np.empty((n_queries, k), np.float32)
    for q in prange(n_queries):
        _unpack_best(heaps[:, q].ravel(), out_position[q], out_similarity[q])
    return out_position, out_similarity


@njit(parallel=True, **JIT)
def _sampled_floors(queries, table, bounds, asking, asking_start, first, sample_at, samples, sampled_rows, k,
                    chunks, floor):
    """Each query's floor (into ``floor``) from its similarities to every FLOOR_STRIDE-th row of
    the cells it probes (``_sampled_floor``), computed by cell as the scan computes them."""
    sampled = np.empty(samples[-1], np.float32)
    for t in prange(chunks):
        for c in range(first[t], first[t + 1]):
            start, first_asking = bounds[c], asking_start[c]
            if sampled_rows[c] == 0 or asking_start[c + 1] == first_asking:
                continue
            block = _asking_block(queries, asking, first_asking, asking_start[c + 1])
            dots = np.dot(block, np.ascontiguousarray(table[start:bounds[c + 1]:FLOOR_STRIDE]).T)
            for a in range(len(block)):
                at = sample_at[first_asking + a]
                sampled[at:at + sampled_rows[c]] = dots[a]
    for q in prange(len(floor)):
        floor[q] = _sampled_floor(sampled[samples[q]:samples[q + 1]], k,
                                  np.empty(samples[q + 1] - samples[q], np.float32))


@njit(inline="always")
def _asking_block(queries, asking, first, last):
    """The features of the queries asking[first:last], one row each."""
    block = np.empty((last - first, queries.shape[1]), np.float32)
    for a in range(len(block)):
        block[a] = queries[asking[first + a]]
    return block


@njit(parallel=True, **JIT)
def _cell_pass(queries, table, bounds, asking, asking_start, first, floor, wanted, k, chunks):
    """cell_top_k's scan: each run of cells (``first``) keeps its own top-k heap of every
    ``wanted`` query, taking what is above the query's ``floor``; a cell's products with every
    query that probes it, so a query's similarities are the same bits in any pass."""
    n_queries = len(queries)
    heaps = np.full((chunks, n_queries, k), _EMPTY, np.uint64)
    for t in prange(chunks):
        for c in range(first[t], first[t + 1]):
            start, n, first_asking = bounds[c], bounds[c + 1] - bounds[c], asking_start[c]
            if n == 0 or asking_start[c + 1] == first_asking:
                continue
            needed = False
            for a in range(first_asking, asking_start[c + 1]):
                needed |= wanted[asking[a]]
            if not needed:
                continue
            block = _asking_block(queries, asking, first_asking, asking_start[c + 1])
            dots = np.dot(block, table[start:start + n].T)
            for a in range(len(block)):
                q = asking[first_asking + a]
                if wanted[q]:
                    _offer_to_heap(heaps[t, q], dots[a], start, floor[q])
    return heaps


QUERY_TILE = 256  # queries per product tile of the exact search
ROW_TILE = 512    # table rows per product tile: 256 x 512 float32 products, 0.5 MB, stay in L2
FLOOR_STRIDE = 16  # every 16th table row sets a top-k list's floor before the pass


@njit(inline="always")
def _sampled_floor(similarities, k, scratch):
    """A starting floor for a query's top-k list from its similarities to every FLOOR_STRIDE-th
    table row: the (3k / stride)-th best of them, about the 3k-th best of all, so the list takes
    some 3k entries instead of nine times k; -inf when the sample is too small. A floor that was
    too high (7 queries in 100,000 on 3DMatch pairs) shows after the pass as fewer than k kept.
    ``scratch``: room for the similarities, selected in place."""
    rank = (3 * k + FLOOR_STRIDE - 1) // FLOOR_STRIDE
    n = len(similarities)
    if rank > n:
        return np.float32(-np.inf)
    for j in range(n):
        scratch[j] = -similarities[j]
    return -_kth_smallest(scratch, n, rank)


@njit(parallel=True, **JIT)
def flat_search(queries, table, slot, k, columns, chunks):
    """Exact search of every query against every table row, all from one pass over the
    products: each query's most similar row (position (Q,), similarity (Q,)); the k most similar
    of the queries with ``slot`` >= 0, in row ``slot`` of (S, k) positions and similarities,
    most similar first; and with ``columns``, each table row's most similar query (position (M,),
    similarity (M,); empty otherwise). Ties go to the lower position.

    The products are computed tile by tile (BLAS), fixed tiles whatever the thread count. The
    query tiles are split into ``chunks`` runs in query order, one per thread, each keeping its
    own best query per row (memory: chunks x M, however many queries); the runs are merged in
    query order, so the result does not depend on ``chunks``. A query's top-k list starts with a
    floor sampled from its tile's products with every FLOOR_STRIDE-th row (``_sampled_floor``);
    a list left with fewer than k is filled again from no floor, from its tile's products
    computed again (the same products to the last bit). A query with a list reads its most
    similar row off the list's first, so only the others scan each tile for their largest."""
    n_queries, n_rows = len(queries), len(table)
    n_slots = 0
    for q in range(n_queries):
        n_slots = max(n_slots, slot[q] + 1)
    nearest = np.full(n_queries, -1, np.int64)
    nearest_similarity = np.full(n_queries, -np.inf, np.float32)
    lists = np.full((n_slots, k + _spare(k)), _EMPTY, np.uint64)
    held = np.zeros(n_slots, np.int64)
    floor = np.full(n_slots, -np.inf, np.float32)
    tiles = (n_queries + QUERY_TILE - 1) // QUERY_TILE
    first_tile = (np.arange(chunks + 1) * tiles) // chunks
    column_runs = chunks if columns else 0
    column_best = np.full((column_runs, n_rows), -np.inf, np.float32)
    column_query = np.full((column_runs, n_rows), -1, np.int64)
    sampled = np.ascontiguousarray(table[::FLOOR_STRIDE])
    for c in prange(chunks):
        passed = np.empty(ROW_TILE, np.int64)
        for t in range(first_tile[c], first_tile[c + 1]):
            q0 = t * QUERY_TILE
            q1 = min(q0 + QUERY_TILE, n_queries)
            if n_slots:
                sample = np.dot(queries[q0:q1], sampled.T)
                scratch = np.empty(len(sampled), np.float32)
                for a in range(q1 - q0):
                    if slot[q0 + a] >= 0:
                        floor[slot[q0 + a]] = _sampled_floor(sample[a], k, scratch)
            for r0 in range(0, n_rows, ROW_TILE):
                r1 = min(r0 + ROW_TILE, n_rows)
                dots = np.dot(queries[q0:q1], table[r0:r1].T)
                for a in range(q1 - q0):
                    q, dot = q0 + a, dots[a]
                    if slot[q] >= 0:  # its list's first is its nearest (below)
                        _offer_to_list(lists[slot[q]], held, floor, slot[q], k, dot, r0, passed)
                    else:
                        top = _largest(dot)
                        if top > nearest_similarity[q]:  # an equal one in a later tile is never better
                            at = 0
                            while dot[at] != top:
                                at += 1
                            nearest_similarity[q], nearest[q] = top, r0 + at
                    if columns:  # queries ascend within a run: an equal one later is never better
                        best_of_row, query_of_row = column_best[c, r0:r1], column_query[c, r0:r1]
                        for j in range(r1 - r0):
                            if dot[j] > best_of_row[j]:
                                best_of_row[j], query_of_row[j] = dot[j], q
    for q in prange(n_queries):  # rare (about 1 in 10,000 on 3DMatch pairs): the tile's products again
        s = slot[q]
        if s >= 0 and held[s] < k and floor[s] > -np.inf:
            lists[s, :], held[s], floor[s] = _EMPTY, 0, -np.inf
            q0 = q - q % QUERY_TILE
            q1 = min(q0 + QUERY_TILE, n_queries)
            for r0 in range(0, n_rows, ROW_TILE):
                r1 = min(r0 + ROW_TILE, n_rows)
                _offer_to_list(lists[s], held, floor, s, k, np.dot(queries[q0:q1], table[r0:r1].T)[q - q0], r0,
                               np.empty(r1 - r0, np.int64))
    candidates = np.empty((n_slots, k), np.int64)
    candidate_similarity = np.empty((n_slots, k), np.float32)
    for s in prange(n_slots):
        _unpack_best(lists[s], candidates[s], candidate_similarity[s])
    for q in prange(n_queries):  # the most similar, ties to the lower position: as the scan above
        if slot[q] >= 0:
            nearest[q], nearest_similarity[q] = candidates[slot[q], 0], candidate_similarity[slot[q], 0]
    row_query = np.full(n_rows if columns else 0, -1, np.int64)
    row_similarity = np.full(n_rows if columns else 0, -np.inf, np.float32)
    for j in prange(len(row_query)):
        for c in range(column_runs):  # runs in query order: an equal one later is never better
            if column_best[c, j] > row_similarity[j]:
                row_similarity[j], row_query[j] = column_best[c, j], column_query[c, j]
    return nearest, nearest_similarity, candidates, candidate_similarity, row_query, row_similarity


GRID_AXIS_BITS = 21  # neighbour_grid: a cell coordinate per axis, three packed in an int64
_GRID_LIMIT = (1 << GRID_AXIS_BITS) - 1
_GRID_EMPTY = -1


@njit(inline="always")
def _pack_cell(i, j, k):
    return (i << (2 * GRID_AXIS_BITS)) | (j << GRID_AXIS_BITS) | k


@njit(inline="always")
def _slot(key, mask):
    return ((key * np.int64(0x9E3779B97F4A7C15)) >> np.int64(17)) & mask


@njit(**JIT)
def grid_keys(coordinates):
    """Packed keys of non-negative integer cell coordinates (N, 3), each below 2**GRID_AXIS_BITS."""
    keys = np.empty(len(coordinates), np.int64)
    for p in range(len(coordinates)):
        keys[p] = _pack_cell(coordinates[p, 0], coordinates[p, 1], coordinates[p, 2])
    return keys


@njit(**JIT)
def grid_table(keys):
    """Open-addressing table (a power of two, at least twice the cells) from a cell's packed key
    to its position in ``keys`` (sorted, unique); _GRID_EMPTY where no cell is."""
    size = 1
    while size < 2 * len(keys):
        size *= 2
    mask = np.int64(size - 1)
    table = np.full(size, _GRID_EMPTY, np.int64)
    for c in range(len(keys)):
        s = _slot(keys[c], mask)
        while table[s] != _GRID_EMPTY:
            s = (s + 1) & mask
        table[s] = c
    return table


@njit(parallel=True, **JIT)
def pooled_counts(at, keys, offsets):
    """For each of ``at`` (non-negative bin keys), how many of ``keys`` fall in a bin at one of
    ``offsets`` from it: a count pooled over a bin's neighbours, in one pass over a hashed table
    of the bins' counts instead of a sort and a search per neighbour."""
    size = 1
    while size < 2 * len(keys):
        size *= 2
    mask = np.int64(size - 1)
    table = np.full(size, _GRID_EMPTY, np.int64)
    counts = np.zeros(size, np.int64)
    for p in range(len(keys)):
        s = _slot(keys[p], mask)
        while table[s] != _GRID_EMPTY and table[s] != keys[p]:
            s = (s + 1) & mask
        table[s] = keys[p]
        counts[s] += 1
    pooled = np.zeros(len(at), np.int64)
    for q in prange(len(at)):
        total = 0
        for o in range(len(offsets)):
            key = at[q] + offsets[o]
            s = _slot(key, mask)
            while table[s] != _GRID_EMPTY:
                if table[s] == key:
                    total += counts[s]
                    break
                s = (s + 1) & mask
        pooled[q] = total
    return pooled


@njit(inline="always")
def _cell_of(key, keys, table, mask):
    s = _slot(key, mask)
    while table[s] != _GRID_EMPTY:
        if keys[table[s]] == key:
            return table[s]
        s = (s + 1) & mask
    return -1


@njit(inline="always")
def _gap(x, a, c, cell):
    """Distance along one axis from coordinate ``x`` (in cell units from the origin, cell ``c``)
    to cell ``a``'s slab."""
    if a == c:
        return 0.0
    if a < c:
        return (x - (a + 1)) * cell
    return (a - x) * cell


@njit(inline="always")
def _flagged(bits, i):
    """Whether bit ``i`` of a bitset of uint64 words is set."""
    return (bits[i >> 6] >> np.uint64(i & 63)) & np.uint64(1) != 0


@njit(**JIT)
def flag_bits(indices, count):
    """A bitset of ``count`` bits (uint64 words) with the bits at ``indices`` set."""
    bits = np.zeros((count + 63) // 64, np.uint64)
    for i in indices:
        bits[i >> 6] |= np.uint64(1) << np.uint64(i & 63)
    return bits


@njit(inline="always")
def _block_flagged(occupied, span, a, b, c):
    """Whether block (a, b, c) of the ``span`` is flagged occupied (False outside the span)."""
    return a < span[0] and b < span[1] and c < span[2] and _flagged(occupied, (a * span[1] + b) * span[2] + c)


@njit(inline="always")
def _grid_nearest_one(qx, qy, qz, origin, cell, threshold, keys, table, starts, order, ordered, mask, occupied, span,
                      shift):
    """The nearest point within ``threshold`` of (qx, qy, qz): (squared distance, index), or
    (threshold squared, len(order)) when none is (grid_nearest says how). ``occupied`` (a bit
    per block of 2**shift cells a side over the ``span`` of blocks, flag_bits, or empty) answers
    for a cell in an empty block without the table."""
    n = len(order)
    best, found = threshold * threshold, n
    x = (qx - origin[0]) / cell
    y = (qy - origin[1]) / cell
    z = (qz - origin[2]) / cell
    if not (-2 < x < _GRID_LIMIT + 2 and -2 < y < _GRID_LIMIT + 2 and -2 < z < _GRID_LIMIT + 2):
        return best, found
    cx, cy, cz = int(np.floor(x)), int(np.floor(y)), int(np.floor(z))
    for ring in range(2):   # the query's own cell first: its best prunes the others
        for a in range(cx - ring, cx + ring + 1):
            if a < 0 or a > _GRID_LIMIT:
                continue
            ga = _gap(x, a, cx, cell)
            for b in range(cy - ring, cy + ring + 1):
                if b < 0 or b > _GRID_LIMIT:
                    continue
                gb = _gap(y, b, cy, cell)
                for c in range(cz - ring, cz + ring + 1):
                    if c < 0 or c > _GRID_LIMIT or max(abs(a - cx), abs(b - cy), abs(c - cz)) != ring:
                        continue
                    gc = _gap(z, c, cz, cell)
                    if ga * ga + gb * gb + gc * gc > best:
                        continue
                    k = _stored_cell(a, b, c, keys, table, mask, occupied, span, shift)
                    if k < 0:
                        continue
                    for p in range(starts[k], starts[k + 1]):
                        dx = ordered[p, 0] - qx
                        dy = ordered[p, 1] - qy
                        dz = ordered[p, 2] - qz
                        d = dx * dx + dy * dy + dz * dz
                        if d < best or (d == best and order[p] < found):
                            best, found = d, order[p]
    return best, found


@njit(parallel=True, **JIT)
def grid_nearest(queries, origin, cell, threshold, keys, table, starts, order, ordered, occupied, span, shift):
    """Each query's nearest point within ``threshold`` (neighbour_grid.NeighbourGrid): the
    query's cell, then the 26 around it (cells are never smaller than the threshold, so these hold
    every point within it), a cell skipped when its nearest face is farther than the best found
    or it is empty; ties go to the lower index. (distance, index), (inf, len) where none is."""
    n, m = len(order), len(queries)
    mask = np.int64(len(table) - 1)
    distance = np.full(m, np.inf)
    index = np.full(m, n, np.int64)
    for q in prange(m):
        best, found = _grid_nearest_one(queries[q, 0], queries[q, 1], queries[q, 2], origin, cell, threshold,
                                        keys, table, starts, order, ordered, mask, occupied, span, shift)
        if found < n and best < threshold * threshold:
            distance[q], index[q] = np.sqrt(best), found
    return distance, index


@njit(inline="always")
def _stored_cell(a, b, c, keys, table, mask, occupied, span, shift):
    """The position of cell (a, b, c) among a grid's occupied cells, -1 when it holds no points
    (its block unflagged, or not in the table)."""
    if len(occupied) and not _block_flagged(occupied, span, a >> shift, b >> shift, c >> shift):
        return -1
    return _cell_of(_pack_cell(a, b, c), keys, table, mask)


@njit(inline="always")
def _cell_range(x, origin, cell, threshold):
    """The cells along one axis that the interval ``x`` +- ``threshold`` touches, inside the grid."""
    return max(int(np.floor((x - threshold - origin) / cell)), 0), \
        min(int(np.floor((x + threshold - origin) / cell)), _GRID_LIMIT)


@njit(parallel=True, **JIT)
def grid_count_within(queries, origin, cell, threshold, keys, table, starts, order, ordered, occupied, span, shift):
    """How many points lie within ``threshold`` of each query (at most, as scipy's ball query
    counts, squared distances summed x, y, z): every cell the box of the threshold around it
    touches (neighbour_grid.NeighbourGrid; grid_nearest's cells)."""
    mask = np.int64(len(table) - 1)
    limit = threshold * threshold
    counts = np.zeros(len(queries), np.int64)
    for q in prange(len(queries)):
        qx, qy, qz = queries[q, 0], queries[q, 1], queries[q, 2]
        a0, a1 = _cell_range(qx, origin[0], cell, threshold)
        b0, b1 = _cell_range(qy, origin[1], cell, threshold)
        c0, c1 = _cell_range(qz, origin[2], cell, threshold)
        for a in range(a0, a1 + 1):
            for b in range(b0, b1 + 1):
                for c in range(c0, c1 + 1):
                    k = _stored_cell(a, b, c, keys, table, mask, occupied, span, shift)
                    if k >= 0:
                        counts[q] += _count_near(ordered, starts[k], starts[k + 1], qx, qy, qz, limit)
    return counts


@njit(inline="always")
def _count_near(ordered, first, last, x, y, z, limit):
    """How many of ``ordered[first:last]`` lie within squared distance ``limit`` of (x, y, z)."""
    count = 0
    for p in range(first, last):
        dx, dy, dz = ordered[p, 0] - x, ordered[p, 1] - y, ordered[p, 2] - z
        count += dx * dx + dy * dy + dz * dz <= limit
    return count


@njit(parallel=True, **JIT)
def grid_pairs_moments(rotations, translations, queries, points, origin, cell, threshold, keys, table, starts,
                       order, ordered, occupied, span, shift):
    """One step of the point-level refinement for each of a batch of poses, in one pass: the
    queries moved by each pose (``rotations`` (b, 3, 3), ``translations`` (b, 3)), each one's
    nearest of ``points`` within ``threshold`` (as grid_nearest), and the Cauchy-weighted moments
    of the pairs found, as estimate.weighted_kabsch forms them: the weighted centroids of the
    moved-from queries and of their nearest points, and the cross-covariance about them. A pose's
    sums run in query order on one thread (the same figures on any number of threads).
    (distance (b, m), index (b, m), count (b,), source centroid (b, 3), target centroid (b, 3),
    cross-covariance (b, 3, 3))."""
    n, m, b = len(order), len(queries), len(rotations)
    mask = np.int64(len(table) - 1)
    distance = np.full((b, m), np.inf)
    index = np.full((b, m), n, np.int64)
    for job in prange(b * m):
        s, q = job // m, job % m
        R, t = rotations[s], translations[s]
        mx = R[0, 0] * queries[q, 0] + R[0, 1] * queries[q, 1] + R[0, 2] * queries[q, 2] + t[0]
        my = R[1, 0] * queries[q, 0] + R[1, 1] * queries[q, 1] + R[1, 2] * queries[q, 2] + t[1]
        mz = R[2, 0] * queries[q, 0] + R[2, 1] * queries[q, 1] + R[2, 2] * queries[q, 2] + t[2]
        best, found = _grid_nearest_one(mx, my, mz, origin, cell, threshold, keys, table, starts, order, ordered,
                                        mask, occupied, span, shift)
        if found < n and best < threshold * threshold:
            distance[s, q], index[s, q] = np.sqrt(best), found
    count = np.zeros(b, np.int64)
    source_centroid = np.zeros((b, 3))
    target_centroid = np.zeros((b, 3))
    cross = np.zeros((b, 3, 3))
    for s in prange(b):
        count[s] = _pair_moments(queries, points, distance[s], index[s], threshold, source_centroid[s],
                                 target_centroid[s], cross[s])
    return distance, index, count, source_centroid, target_centroid, cross


@njit(inline="always")
def _cauchy(residual, threshold):
    """The refinements' robust weight: a residual at the threshold counts half, far ones fade
    without a cut-off."""
    r = residual / threshold
    return 1.0 / (1.0 + r * r)


@njit(parallel=True, **JIT)
def fixed_pairs_moments(rotations, translations, source, target, threshold):
    """grid_pairs_moments for fixed correspondences (``source[i]``, ``target[i]``): each pair's
    residual under each pose, and the Cauchy-weighted moments of those within ``threshold``, as
    estimate.weighted_kabsch forms them. (distance (b, m), count (b,), source centroid (b, 3),
    target centroid (b, 3), cross-covariance (b, 3, 3))."""
    m, b = len(source), len(rotations)
    distance = np.full((b, m), np.inf)
    for job in prange(b * m):
        s, q = job // m, job % m
        R, t = rotations[s], translations[s]
        dx = R[0, 0] * source[q, 0] + R[0, 1] * source[q, 1] + R[0, 2] * source[q, 2] + t[0] - target[q, 0]
        dy = R[1, 0] * source[q, 0] + R[1, 1] * source[q, 1] + R[1, 2] * source[q, 2] + t[1] - target[q, 1]
        dz = R[2, 0] * source[q, 0] + R[2, 1] * source[q, 1] + R[2, 2] * source[q, 2] + t[2] - target[q, 2]
        d = np.sqrt(dx * dx + dy * dy + dz * dz)
        if d < threshold:
            distance[s, q] = d
    index = np.arange(m)
    count = np.zeros(b, np.int64)
    source_centroid = np.zeros((b, 3))
    target_centroid = np.zeros((b, 3))
    cross = np.zeros((b, 3, 3))
    for s in prange(b):
        count[s] = _pair_moments(source, target, distance[s], index, threshold, source_centroid[s],
                                 target_centroid[s], cross[s])
    return distance, count, source_centroid, target_centroid, cross


@njit(**JIT)
def plane_step_system(moved, distance, nearest, points, normals, threshold):
    """The normal equations of one point-to-plane Gauss-Newton step (estimate.plane_refine) in
    one pass: for the moved points paired within ``threshold`` (``distance``, ``nearest`` as
    grid_nearest gives them), each one's residual along its nearest point's normal and its
    Jacobian row [arm x normal, normal], the arm from the paired points' centroid, Cauchy-weighted:
    (pairs, centroid (3,), J^T W J (6, 6), J^T W r (6,)). In point order on one thread (a scan's
    few thousand pairs are no work for a second)."""
    count = 0
    centre = np.zeros(3)
    for i in range(len(moved)):
        if distance[i] < threshold:
            count += 1
            for a in range(3):
                centre[a] += moved[i, a]
    system = np.zeros((6, 6))
    gradient = np.zeros(6)
    if count == 0:
        return count, centre, system, gradient
    centre /= count
    row = np.empty(6)
    for i in range(len(moved)):
        if distance[i] < threshold:
            q = nearest[i]
            nx, ny, nz = normals[q, 0], normals[q, 1], normals[q, 2]
            ax, ay, az = moved[i, 0] - centre[0], moved[i, 1] - centre[1], moved[i, 2] - centre[2]
            residual = ((moved[i, 0] - points[q, 0]) * nx + (moved[i, 1] - points[q, 1]) * ny
                        + (moved[i, 2] - points[q, 2]) * nz)
            row[0], row[1], row[2] = ay * nz - az * ny, az * nx - ax * nz, ax * ny - ay * nx
            row[3], row[4], row[5] = nx, ny, nz
            weight = _cauchy(residual, threshold)
            for a in range(6):
                gradient[a] += weight * row[a] * residual
                for b in range(6):
                    system[a, b] += weight * row[a] * row[b]
    return count, centre, system, gradient


@njit(inline="always")
def _pair_moments(queries, points, distance, index, threshold, source_centroid, target_centroid, cross):
    """grid_pairs_moments' sums for one pose, into the last three arguments; the pairs' count."""
    m = len(queries)
    weight = np.zeros(m)
    count = 0
    total = 0.0
    for q in range(m):
        if distance[q] < threshold:
            weight[q] = _cauchy(distance[q], threshold)
            count += 1
            total += weight[q]
            for i in range(3):
                source_centroid[i] += weight[q] * queries[q, i]
                target_centroid[i] += weight[q] * points[index[q], i]
    for i in range(3):
        source_centroid[i] /= total + 1e-6
        target_centroid[i] /= total + 1e-6
    for q in range(m):
        if weight[q] > 0:
            for i in range(3):
                a = weight[q] * (queries[q, i] - source_centroid[i])
                for j in range(3):
                    cross[i, j] += a * (points[index[q], j] - target_centroid[j])
    return count


@njit(inline="always")
def _nearest_within(p, x, y, z, block, block_index, m, radius2, out, candidate, candidate_d2, scratch):
    """The up to len(``out``) points of the first ``m`` of ``block`` (x, y, z rows; their indices
    ``block_index``) nearest (x, y, z) within the radius (squared ``radius2``), point ``p`` itself
    left out, into ``out`` (ties at the cut-off to the lower index); their number. ``scratch``:
    room for the selection of the cut-off."""
    for i in range(m):   # one pass the compiler vectorises, then the ones within, without a branch
        dx, dy, dz = block[0, i] - x, block[1, i] - y, block[2, i] - z
        candidate_d2[i] = dx * dx + dy * dy + dz * dz
    n = 0
    for i in range(m):
        d2 = candidate_d2[i]
        candidate[n], candidate_d2[n] = block_index[i], d2
        n += (d2 <= radius2) & (block_index[i] != p)
    most = len(out)
    if n <= most:
        out[:n] = candidate[:n]
        return n
    scratch[:n] = candidate_d2[:n]
    cut = _kth_smallest(scratch, n, most)
    kept = 0
    for i in range(n):
        if candidate_d2[i] < cut:
            out[kept] = candidate[i]
            kept += 1
    tied = 0
    for i in range(n):   # candidates ascend in cells, not in index: the tied ones sorted
        if candidate_d2[i] == cut:
            candidate[tied] = candidate[i]
            tied += 1
    if tied > 1:
        candidate[:tied].sort()
    out[kept:] = candidate[:most - kept]
    return most


# cos of the bin edges of an angle in [-pi, pi] cut into 11: edges 1-5 below 0, 6-10 above
_EDGE_COS = np.cos(-np.pi + 2.0 * np.pi * np.arange(1, 11) / 11)


@njit(inline="always")
def _cosine_bin(c):
    """floor(11 (c + 1) / 2), clamped to 0-10: a cosine's bin."""
    return min(max(np.int64(np.floor(11 * (c + 1.0) * 0.5)), 0), 10)


@njit(inline="always")
def _spfh_bins(points, normals, p, neighbours, count, gathered, bins):
    """The three FPFH bins (0-10 each, into ``bins``' three rows) of point ``p`` paired with each
    of its ``count`` neighbours, in Rusu's Darboux frame taken at the point whose normal is
    closer to the line between them; a pair with no frame (coincident points, a normal along the
    line) counts as all angles zero, the middle bins, as Open3D counts it. The neighbours are
    first gathered (into ``gathered``) and every choice is a select, so the compiler vectorises
    the pairs (a third of the time of one pair at a time, the same bins). The angle's bin
    (floor(11 (atan2(y, x) + pi) / 2 pi)) is the count of edges its cosine has passed within its
    half-plane, where the angle is monotonic in it: no arctangent."""
    for i in range(count):
        q = neighbours[i]
        for a in range(3):
            gathered[a, i], gathered[3 + a, i] = points[q, a], normals[q, a]
    px, py, pz = points[p, 0], points[p, 1], points[p, 2]
    npx, npy, npz = normals[p, 0], normals[p, 1], normals[p, 2]
    e0, e1, e2, e3, e4 = _EDGE_COS[0], _EDGE_COS[1], _EDGE_COS[2], _EDGE_COS[3], _EDGE_COS[4]
    e5, e6, e7, e8, e9 = _EDGE_COS[5], _EDGE_COS[6], _EDGE_COS[7], _EDGE_COS[8], _EDGE_COS[9]
    for i in range(count):
        dx, dy, dz = gathered[0, i] - px, gathered[1, i] - py, gathered[2, i] - pz
        nqx, nqy, nqz = gathered[3, i], gathered[4, i], gathered[5, i]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        cos1 = (npx * dx + npy * dy + npz * dz) / length
        cos2 = (nqx * dx + nqy * dy + nqz * dz) / length
        swap = abs(cos1) < abs(cos2)   # the frame at the other point (arccos is decreasing)
        ux, uy, uz = (nqx if swap else npx), (nqy if swap else npy), (nqz if swap else npz)
        wx, wy, wz = (npx if swap else nqx), (npy if swap else nqy), (npz if swap else nqz)
        phi = -cos2 if swap else cos1
        ex, ey, ez = (-dx if swap else dx), (-dy if swap else dy), (-dz if swap else dz)
        vx, vy, vz = ey * uz - ez * uy, ez * ux - ex * uz, ex * uy - ey * ux
        v_norm = np.sqrt(vx * vx + vy * vy + vz * vz)
        vx, vy, vz = vx / v_norm, vy / v_norm, vz / v_norm
        sx, sy, sz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        y, x = sx * wx + sy * wy + sz * wz, ux * wx + uy * wy + uz * wz
        r = np.sqrt(x * x + y * y)
        c = x / r if r > 0.0 else 1.0
        below = (np.int64(c >= e0) + np.int64(c >= e1) + np.int64(c >= e2) + np.int64(c >= e3)
                 + np.int64(c >= e4))
        above = (5 + np.int64(c <= e5) + np.int64(c <= e6) + np.int64(c <= e7) + np.int64(c <= e8)
                 + np.int64(c <= e9))
        framed = (length != 0.0) & (v_norm != 0.0)
        bins[0, i] = (above if y >= 0.0 else below) if framed else 5
        bins[1, i] = _cosine_bin(vx * wx + vy * wy + vz * wz) if framed else 5
        bins[2, i] = _cosine_bin(phi) if framed else 5


@njit
def _most_around(starts):
    """The most points 27 cells of a grid (its ``starts``) can hold."""
    most = 0
    for k in range(len(starts) - 1):
        most = max(most, 27 * (starts[k + 1] - starts[k]))
    return most


@njit(inline="always")
def _gather_around(cell_at, keys, table, starts, order, ordered, block, block_index):
    """The points of occupied cell ``cell_at`` and of the 26 around it into ``block`` (x, y, z
    rows) and their indices into ``block_index``; their number."""
    mask = np.int64(len(table) - 1)
    low = np.int64((1 << GRID_AXIS_BITS) - 1)
    key = keys[cell_at]
    cx, cy, cz = key >> (2 * GRID_AXIS_BITS), (key >> GRID_AXIS_BITS) & low, key & low
    m = 0
    for a in range(max(cx - 1, 0), min(cx + 1, _GRID_LIMIT) + 1):
        for b in range(max(cy - 1, 0), min(cy + 1, _GRID_LIMIT) + 1):
            for c in range(max(cz - 1, 0), min(cz + 1, _GRID_LIMIT) + 1):
                k = _cell_of(_pack_cell(a, b, c), keys, table, mask)
                if k < 0:
                    continue
                for q in range(starts[k], starts[k + 1]):
                    block[0, m], block[1, m], block[2, m] = ordered[q, 0], ordered[q, 1], ordered[q, 2]
                    block_index[m] = order[q]
                    m += 1
    return m


@njit(inline="always")
def _eigenvector_of(a00, a01, a02, a11, a12, a22, value):
    """A unit eigenvector of the symmetric matrix for its eigenvalue ``value``, when that one is
    apart from the other two: the longest cross product of two rows of the matrix less the value
    (each is perpendicular to it)."""
    r0x, r0y, r0z = a00 - value, a01, a02
    r1x, r1y, r1z = a01, a11 - value, a12
    r2x, r2y, r2z = a02, a12, a22 - value
    ax, ay, az = r0y * r1z - r0z * r1y, r0z * r1x - r0x * r1z, r0x * r1y - r0y * r1x
    bx, by, bz = r0y * r2z - r0z * r2y, r0z * r2x - r0x * r2z, r0x * r2y - r0y * r2x
    cx, cy, cz = r1y * r2z - r1z * r2y, r1z * r2x - r1x * r2z, r1x * r2y - r1y * r2x
    d0, d1, d2 = ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz, cx * cx + cy * cy + cz * cz
    if d1 > d0 and d1 >= d2:
        length = np.sqrt(d1)
        return bx / length, by / length, bz / length
    if d2 > d0 and d2 > d1:
        length = np.sqrt(d2)
        return cx / length, cy / length, cz / length
    length = np.sqrt(d0)
    return ax / length, ay / length, az / length


@njit(inline="always")
def _unit_pair(a, b):
    """(a, b) scaled to unit length up to sign, the larger divided out first (no overflow)."""
    if abs(a) >= abs(b):
        b /= a
        a = 1 / np.sqrt(1 + b * b)
        return a, b * a
    a /= b
    b = 1 / np.sqrt(1 + a * a)
    return a * b, b


@njit(inline="always")
def _second_eigenvector(a00, a01, a02, a11, a12, a22, ex, ey, ez, value):
    """A unit eigenvector for eigenvalue ``value``, perpendicular to the unit eigenvector (ex, ey,
    ez) already found: the null direction of the matrix less the value within the plane normal to
    that vector (robust when the two remaining eigenvalues are close)."""
    if abs(ex) > abs(ey):
        inverse = 1 / np.sqrt(ex * ex + ez * ez)
        ux, uy, uz = -ez * inverse, 0.0, ex * inverse
    else:
        inverse = 1 / np.sqrt(ey * ey + ez * ez)
        ux, uy, uz = 0.0, ez * inverse, -ey * inverse
    vx, vy, vz = ey * uz - ez * uy, ez * ux - ex * uz, ex * uy - ey * ux
    aux, auy, auz = a00 * ux + a01 * uy + a02 * uz, a01 * ux + a11 * uy + a12 * uz, a02 * ux + a12 * uy + a22 * uz
    avx, avy, avz = a00 * vx + a01 * vy + a02 * vz, a01 * vx + a11 * vy + a12 * vz, a02 * vx + a12 * vy + a22 * vz
    m00 = ux * aux + uy * auy + uz * auz - value
    m01 = ux * avx + uy * avy + uz * avz
    m11 = vx * avx + vy * avy + vz * avz - value
    if abs(m00) >= abs(m11):
        if max(abs(m00), abs(m01)) == 0:
            return ux, uy, uz
        a, b = _unit_pair(m00, m01)
        return b * ux - a * vx, b * uy - a * vy, b * uz - a * vz
    if max(abs(m11), abs(m01)) == 0:
        return ux, uy, uz
    a, b = _unit_pair(m11, m01)
    return a * ux - b * vx, a * uy - b * vy, a * uz - b * vz


@njit(inline="always")
def _least_spread(c00, c01, c02, c11, c12, c22):
    """The unit eigenvector of the smallest eigenvalue of the symmetric 3 x 3 matrix, as Open3D's
    fast solver gives it, sign included (the eigenvalues in closed form, the trigonometric solution
    of the characteristic cubic, on the matrix scaled by its largest entry); (0, 0, 0) for the zero
    matrix."""
    scale = max(c00, c01, c02, c11, c12, c22)
    if scale == 0:
        return 0.0, 0.0, 0.0
    a00, a01, a02, a11, a12, a22 = c00 / scale, c01 / scale, c02 / scale, c11 / scale, c12 / scale, c22 / scale
    off = a01 * a01 + a02 * a02 + a12 * a12
    if not off > 0:   # diagonal: the axis of the least entry (compared scaled back, as Open3D does)
        d00, d11, d22 = a00 * scale, a11 * scale, a22 * scale
        if d00 < d11 and d00 < d22:
            return 1.0, 0.0, 0.0
        if d11 < d00 and d11 < d22:
            return 0.0, 1.0, 0.0
        return 0.0, 0.0, 1.0
    q = (a00 + a11 + a22) / 3
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + off * 2) / 6)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)) / (p * p * p)
    half_det = min(max(det * 0.5, -1.0), 1.0)
    angle = np.arccos(half_det) / 3.0
    high = np.cos(angle) * 2
    low = np.cos(angle + 2.09439510239319549) * 2
    value0, value1, value2 = q + p * low, q + p * -(low + high), q + p * high
    # the eigenvalue farthest from the other two first, its vector by cross products; the second
    # perpendicular to it; the third their cross product
    if half_det >= 0:
        ex, ey, ez = _eigenvector_of(a00, a01, a02, a11, a12, a22, value2)
        if value2 < value0 and value2 < value1:
            return ex, ey, ez
    else:
        ex, ey, ez = _eigenvector_of(a00, a01, a02, a11, a12, a22, value0)
        if value0 < value1 and value0 < value2:
            return ex, ey, ez
    fx, fy, fz = _second_eigenvector(a00, a01, a02, a11, a12, a22, ex, ey, ez, value1)
    if value1 < value0 and value1 < value2:
        return fx, fy, fz
    if half_det >= 0:
        return fy * ez - fz * ey, fz * ex - fx * ez, fx * ey - fy * ex
    return ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx


@njit(inline="always")
def _normal_of(points, neighbourhood, k):
    """Open3D's normal of the first ``k`` rows of ``neighbourhood``: the least spread of their
    covariance, its moments summed in that order; (0, 0, 1) for fewer than three points or no
    spread."""
    if k < 3:
        return 0.0, 0.0, 1.0
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
    for i in range(k):
        x, y, z = points[neighbourhood[i], 0], points[neighbourhood[i], 1], points[neighbourhood[i], 2]
        s0, s1, s2 = s0 + x, s1 + y, s2 + z
        s3, s4, s5, s6, s7, s8 = s3 + x * x, s4 + x * y, s5 + x * z, s6 + y * y, s7 + y * z, s8 + z * z
    s0, s1, s2, s3, s4, s5, s6, s7, s8 = s0 / k, s1 / k, s2 / k, s3 / k, s4 / k, s5 / k, s6 / k, s7 / k, s8 / k
    x, y, z = _least_spread(s3 - s0 * s0, s4 - s0 * s1, s5 - s0 * s2, s6 - s1 * s1, s7 - s1 * s2, s8 - s2 * s2)
    if x == 0.0 and y == 0.0 and z == 0.0:
        return 0.0, 0.0, 1.0
    return x, y, z


@njit(**JIT)
def normal_of(points, neighbourhood):
    """Open3D's normal from a point's neighbourhood in the order given (the point first)."""
    return np.array(_normal_of(points, neighbourhood, len(neighbourhood)))


@njit(parallel=True, **JIT)
def surface_normals(points, radius, max_nn, keys, table, starts, order, ordered):
    """(N, 3) unit normals in Open3D's arithmetic (its hybrid search's neighbourhood: the
    ``max_nn`` nearest within ``radius``, the point itself counted, in ascending distance; their
    moments summed in that order; its fast eigen solver), signed as the solver gives them, on
    neighbour_grid's grid of cells no smaller than the radius; and whether two of a point's
    neighbours tie in distance and their order (Open3D's is its kd-tree's, not known here) or, at
    the cut-off, which is kept changes the normal (normal_of takes Open3D's order). Points are
    independent: the same normals whatever the threads."""
    n = len(points)
    normals = np.empty((n, 3))
    tied = np.zeros(n, np.bool_)
    radius2 = radius * radius
    most_candidates = _most_around(starts)
    for cell_at in prange(len(keys)):
        block = np.empty((3, most_candidates))
        block_index = np.empty(most_candidates, np.int64)
        candidate = np.empty(most_candidates, np.int64)
        candidate_d2 = np.empty(most_candidates)
        nearest = np.empty(max_nn + 1, np.int64)   # one more than kept: a tie at the cut-off shows
        nearest_d2 = np.empty(max_nn + 1)
        m = _gather_around(cell_at, keys, table, starts, order, ordered, block, block_index)
        for at in range(starts[cell_at], starts[cell_at + 1]):
            p = order[at]
            x, y, z = ordered[at, 0], ordered[at, 1], ordered[at, 2]
            for i in range(m):   # one pass the compiler vectorises, then the ones within, without a branch
                dx, dy, dz = x - block[0, i], y - block[1, i], z - block[2, i]
                candidate_d2[i] = dx * dx + dy * dy + dz * dz
            within = 0
            for i in range(m):
                d2 = candidate_d2[i]
                candidate[within], candidate_d2[within] = block_index[i], d2
                within += d2 < radius2
            count = 0
            for i in range(within):   # the nearest by insertion, in ascending distance, ties in the order met
                d2 = candidate_d2[i]
                if count == max_nn + 1 and d2 >= nearest_d2[max_nn]:
                    continue
                slot = min(count, max_nn)
                while slot > 0 and nearest_d2[slot - 1] > d2:
                    nearest[slot], nearest_d2[slot] = nearest[slot - 1], nearest_d2[slot - 1]
                    slot -= 1
                nearest[slot], nearest_d2[slot] = candidate[i], d2
                count = min(count + 1, max_nn + 1)
            kept = min(count, max_nn)
            nx, ny, nz = _normal_of(points, nearest, kept)
            normals[p, 0], normals[p, 1], normals[p, 2] = nx, ny, nz
            # ties: flagged where their order (or, at the cut-off, which is kept) may change the
            # normal; one tied pair is summed the other way round to see, more are not tried
            pairs, at_pair = 0, 0
            for i in range(count - 1):
                if nearest_d2[i] == nearest_d2[i + 1]:
                    pairs += 1 if i + 1 < kept else 2
                    at_pair = i
            if pairs == 1:
                nearest[at_pair], nearest[at_pair + 1] = nearest[at_pair + 1], nearest[at_pair]
                sx, sy, sz = _normal_of(points, nearest, kept)
                tied[p] = sx != nx or sy != ny or sz != nz
            else:
                tied[p] = pairs > 1
    return normals, tied


@njit(parallel=True, **JIT)
def fpfh_features(points, normals, radius, max_nn, keys, table, starts, order, ordered):
    """(N, 33) FPFH (features.fpfh) of every point, its neighbours the ``max_nn`` - 1 nearest
    within ``radius``, found on neighbour_grid's grid of cells no smaller than the radius (its
    keys, table, starts, order and ordered points): first each point's own histogram of pair
    angles (SPFH, each third summing to 100), then each point's SPFH plus its neighbours',
    weighted by one over the squared distance and each third normalised to 100. Points are
    independent: the same sums in the same order whatever the threads."""
    n = len(points)
    radius2 = radius * radius
    most_candidates = _most_around(starts)
    neighbours = np.empty((n, max(max_nn - 1, 0)), np.int32)  # a neighbourhood of max_nn counts the point
    counts = np.zeros(n, np.int64)
    for cell_at in prange(len(keys)):   # the points of a cell share the 27 cells around it
        block = np.empty((3, most_candidates))
        block_index = np.empty(most_candidates, np.int64)
        candidate = np.empty(most_candidates, np.int64)
        candidate_d2 = np.empty(most_candidates)
        scratch = np.empty(most_candidates)
        m = _gather_around(cell_at, keys, table, starts, order, ordered, block, block_index)
        for at in range(starts[cell_at], starts[cell_at + 1]):
            p = order[at]
            counts[p] = _nearest_within(p, ordered[at, 0], ordered[at, 1], ordered[at, 2], block, block_index,
                                        m, radius2, neighbours[p], candidate, candidate_d2, scratch)
    spfh = np.zeros((n, 33))
    for p in prange(n):
        if counts[p] == 0:
            continue
        gathered = np.empty((6, counts[p]))
        bins = np.empty((3, counts[p]), np.int64)
        _spfh_bins(points, normals, p, neighbours[p], counts[p], gathered, bins)
        step = 100.0 / counts[p]
        for i in range(counts[p]):
            spfh[p, bins[0, i]] += step
            spfh[p, 11 + bins[1, i]] += step
            spfh[p, 22 + bins[2, i]] += step
    fpfh = np.zeros((n, 33))
    for p in prange(n):
        if counts[p] == 0:
            continue
        for i in range(counts[p]):
            q = neighbours[p, i]
            dx, dy, dz = points[q, 0] - points[p, 0], points[q, 1] - points[p, 1], points[q, 2] - points[p, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 == 0.0:
                continue
            weight = 1.0 / d2
            for j in range(33):
                fpfh[p, j] += spfh[q, j] * weight
        for third in range(3):
            total = 0.0
            for j in range(11 * third, 11 * third + 11):
                total += fpfh[p, j]
            scale = 100.0 / total if total != 0.0 else 0.0
            for j in range(11 * third, 11 * third + 11):
                fpfh[p, j] = fpfh[p, j] * scale + spfh[p, j]
    return fpfh


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel for the types the pipeline passes,
    under the BLAS limit a registration runs them under (cell_top_k's products would otherwise
    start scipy's OpenBLAS threads, which took the node's cores under load)."""
    with blas_on_one_thread():
        points = np.random.default_rng(0).random((8, 3))
        compatibility_matrices(points, points, 0.1, np.zeros(8), 0.0, False)
        starts, columns, soft, hard, tight = compatibility_matrices(points, points, 0.1, np.zeros(8), 0.0, True)
        sparse_leading_eigenvector(starts, columns, soft, 2)
        second_order_top_k(tight, starts, columns, np.arange(3, dtype=np.int64), 2)
        seed_consensus(np.zeros((2, 3), np.int64), hard, points, points, 0.1, np.zeros(8), 0.0, True, 2, 2)
        triangle_scores(points, points, 0.1, 2)
        generalized_mutual_pairs(np.random.default_rng(0).random((2, 4, 5)).astype(np.float32), 3)
        landed_counts(np.zeros((2, 3, 3)), np.zeros((2, 3)), np.zeros((8, 3)), np.zeros((3, 8, 4), np.float32),
                      np.float32(0.01))
        verified_candidates(np.zeros((2, 8, 3), np.float32), np.zeros((3, 8, 4), np.float32),
                            np.zeros((8, 4), np.float32), np.float32(0.01), np.float32(0.02))
        most_length_agreement(points, points, np.arange(3, dtype=np.int64), 0.05)
        fixed_pairs_moments(np.eye(3)[None], np.zeros((1, 3)), points, points, 0.1)
        plane_step_system(points, np.zeros(8), np.zeros(8, np.int64), points, points, 0.1)
        region_agreement(points.reshape(2, 4, 3), points.reshape(2, 4, 3), np.ones((2, 4), np.bool_), 0.05)
        spherical_bins(points, 0.01, 8, 1e-3)
        free_space_classes(points, np.zeros(3), np.ones((4, 8), np.float32), 0.01, 1e-3, 0.1, 0.01, np.zeros(8))
        splatted_free_depth(np.arange(3, dtype=np.int64), np.ones(3, np.float32), np.ones(3, np.int64), 2, 4, 0)
        within_any(points, points[:2], np.ones(2))
        greedy_apart(points[:2].copy(), np.zeros((2, 3), np.int64), np.arange(2, dtype=np.int64), 0.1)
        pooled_counts(np.arange(3, dtype=np.int64), np.arange(4, dtype=np.int64), np.arange(2, dtype=np.int64))
        keys = np.unique(grid_keys(np.zeros((2, 3), np.int64)))
        grid = (keys, grid_table(keys), np.array([0, 2], np.int64), np.arange(2, dtype=np.int64), points[:2].copy(),
                flag_bits(np.zeros(1, np.int64), 1), np.ones(3, np.int64), 0)
        grid_nearest(points, np.zeros(3), 0.1, 0.1, *grid)
        grid_count_within(points, np.zeros(3), 0.1, 0.1, *grid)
        grid_pairs_moments(np.eye(3)[None], np.zeros((1, 3)), points, points[:2].copy(), np.zeros(3), 0.1, 0.1, *grid)
        flat_search(np.zeros((2, 4), np.float32), np.zeros((3, 4), np.float32), np.array([0, -1], np.int64), 2, True, 2)
        cell_top_k(np.zeros((2, 4), np.float32), np.zeros((2, 1), np.int64), np.zeros((3, 4), np.float32),
                   np.array([0, 3], np.int64), 2, 2)
        normals = np.tile([0.0, 0.0, 1.0], (2, 1))
        fpfh_features(points[:2].copy(), normals, 0.1, 3, keys, grid_table(keys), np.array([0, 2], np.int64),
                      np.arange(2, dtype=np.int64), points[:2].copy())
        surface_normals(points[:2].copy(), 0.1, 3, keys, grid_table(keys), np.array([0, 2], np.int64),
                        np.arange(2, dtype=np.int64), points[:2].copy())
        normal_of(points[:2].copy(), np.arange(2, dtype=np.int64))
