"""Small compiled helpers more than one domain's kernels share: the k-th smallest of a list, the
extremes of a row, a flag of a packed bit row, the row of a sorted table."""
from __future__ import annotations

import numpy as np
from numba import njit


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


@njit(inline="always")
def _flagged(bits, i):
    """Whether bit ``i`` of a bitset of uint64 words is set."""
    return (bits[i >> 6] >> np.uint64(i & 63)) & np.uint64(1) != 0
