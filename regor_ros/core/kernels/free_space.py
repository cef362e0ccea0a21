"""Kernels of the free-space check (core/range_image.py, gate/visibility.py, map_view.py): directions
binned on the sensor's sphere, each point's class against a range image, the splatted free depth, and
points within any of a set of spheres."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .threads import JIT


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
