"""Kernels of the neighbour grid (core/neighbour_grid.py) and the refinements (core/estimate.py):
packed cell keys and their table, pooled counts, the nearest keypoint within a threshold, counts
within a radius, the refinements' moments and plane steps, and points kept apart by a radius."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .common import _flagged, _kth_smallest, _row_at
from .threads import JIT


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
