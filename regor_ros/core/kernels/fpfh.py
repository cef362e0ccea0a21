"""Kernels of the features (core/features.py): Open3D's normals to the bit, and FPFH's histograms."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .grid import _GRID_LIMIT, GRID_AXIS_BITS, _cell_of, _nearest_within, _pack_cell
from .threads import JIT

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
