"""Each query point's nearest keypoint within a threshold: the refinements' one question.

The refinements ask it 20 to 50 times per registration, every source keypoint each time, always
within a small threshold (tau_e and its halves). A kd-tree answers any radius; a hashed grid of
cells the threshold's size answers this one by looking in the query's cell and the 26 around it,
its own first, skipping a cell that cannot hold anything nearer than what was found: the same
nearest keypoints as the kd-tree, sooner. A grid is built the first time a threshold is asked for
and kept, so a map pays for it once. A grid also flags its occupied cells, a bit each (or a bit
per block of cells in a box too large for that): a query off the surfaces (most of a rival's)
then skips its empty neighbours for a read each.
"""
from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np

from . import kernels
from .geometry import column_bounds


class PairMoments(NamedTuple):
    """Poses' nearest pairs within a threshold and their Cauchy-weighted moments: what one step
    of the point-level refinement needs (estimate.kabsch_from_moments), for each of b poses."""

    distance: np.ndarray            # (b, m) each query's distance to its nearest point, inf where none is within
    nearest: np.ndarray             # (b, m) that point's index
    paired: np.ndarray              # (b,) the pairs within the threshold
    source_centroid: np.ndarray     # (b, 3) weighted, of the queries paired (before the pose moves them)
    target_centroid: np.ndarray     # (b, 3) weighted, of their nearest points
    cross_covariance: np.ndarray    # (b, 3, 3) sum of w (query - its centroid)(nearest - its centroid)^T


OCCUPANCY_BITS = 1 << 28  # a grid flags its occupied cells in at most this many bits (32 MB) ...
OCCUPANCY_MAX_SHIFT = 3   # ... a bit per block of up to 8 x 8 x 8 cells; beyond that, none


class Cells(NamedTuple):
    """A grid of one threshold: the kernels' arguments (kernels.grid_nearest)."""

    origin: np.ndarray     # (3,) the corner of cell (0, 0, 0)
    cell: float            # the cells' size
    keys: np.ndarray       # the occupied cells' packed coordinates, sorted
    table: np.ndarray      # open addressing: a key's slot -> its position in keys
    starts: np.ndarray     # each occupied cell's first point in order, and the end
    order: np.ndarray      # the points' indices, sorted by cell
    ordered: np.ndarray    # the points in that order
    occupied: np.ndarray   # a bit per block of the span (x, y, z order; uint64 words), or empty when it is too large
    span: np.ndarray       # (3,) blocks along each axis
    shift: int             # a block is 2**shift cells a side


class NeighbourGrid:
    """The nearest of ``points`` within a threshold of each query, one grid per threshold."""

    def __init__(self, points: np.ndarray):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self._grids: dict[float, Cells] = {}
        self._lock = threading.Lock()

    def nearest_within(self, queries: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """(distance, index) of each query's nearest point within ``threshold``: (inf, len(points))
        where there is none, as scipy's kd-tree answers with ``distance_upper_bound``."""
        queries = np.ascontiguousarray(queries, dtype=np.float64)
        if len(self.points) == 0:
            return np.full(len(queries), np.inf), np.zeros(len(queries), dtype=np.int64)
        origin, cell, *grid = self.cells(float(threshold))
        return kernels.grid_nearest(queries, origin, cell, float(threshold), *grid)

    def count_within(self, queries: np.ndarray, threshold: float) -> np.ndarray:
        """How many points lie within ``threshold`` of each query, as scipy's kd-tree counts them
        (``query_ball_point(..., return_length=True)``)."""
        queries = np.ascontiguousarray(queries, dtype=np.float64)
        if len(self.points) == 0:
            return np.zeros(len(queries), dtype=np.int64)
        origin, cell, *grid = self.cells(float(threshold))
        return kernels.grid_count_within(queries, origin, cell, float(threshold), *grid)

    def pair_moments(self, poses: np.ndarray, queries: np.ndarray, threshold: float) -> PairMoments:
        """The queries moved by each of ``poses`` (b, 4, 4) paired with their nearest points within
        ``threshold``, and the pairs' moments, in one compiled pass (the refinement's numpy glue
        around nearest_within cost as much as the search)."""
        queries = np.ascontiguousarray(queries, dtype=np.float64)
        b, m = len(poses), len(queries)
        if len(self.points) == 0:
            return PairMoments(np.full((b, m), np.inf), np.zeros((b, m), dtype=np.int64), np.zeros(b, dtype=np.int64),
                               np.zeros((b, 3)), np.zeros((b, 3)), np.zeros((b, 3, 3)))
        origin, cell, *grid = self.cells(float(threshold))
        rotations = np.ascontiguousarray(poses[:, :3, :3], dtype=np.float64)
        translations = np.ascontiguousarray(poses[:, :3, 3], dtype=np.float64)
        return PairMoments(*kernels.grid_pairs_moments(rotations, translations, queries, self.points, origin, cell,
                                                       float(threshold), *grid))

    def cells(self, threshold: float) -> Cells:
        """The grid for ``threshold``, built the first time it is asked for."""
        with self._lock:
            if threshold not in self._grids:
                self._grids[threshold] = self._build(threshold)
            return self._grids[threshold]

    def _build(self, threshold: float) -> Cells:
        """Cells of the threshold's size (larger when the cloud spans more cells than the packed
        key holds: each then holds more points), the points sorted by cell, and an
        open-addressing table from a cell's key to its run of points. A query off the surfaces
        (a wrong pose's, a rival's) finds most of its 27 cells empty: a bit per cell flags the
        occupied ones, so an empty cell costs one read instead of a hashed probe. Where the
        cloud's box spans more cells than OCCUPANCY_BITS (a map a kilometre wide at the finest
        threshold), a bit flags a block of 2, 4 or 8 cells a side instead: an empty block still
        answers for its cells, and a block as large as a building's facade no longer would."""
        origin, top = column_bounds(self.points)
        extent = float((top - origin).max())
        cell = max(threshold, extent / (2 ** kernels.GRID_AXIS_BITS - 2), 1e-9)
        coordinates = np.floor((self.points - origin) / cell).astype(np.int64)
        packed = kernels.grid_keys(coordinates)
        order = np.argsort(packed, kind="stable")
        keys, starts = np.unique(packed[order], return_index=True)
        starts = np.append(starts, len(order)).astype(np.int64)
        table = kernels.grid_table(keys)
        top_cell = column_bounds(coordinates)[1]
        occupied, span, shift = np.zeros(0, dtype=np.uint64), np.ones(3, dtype=np.int64), 0
        for blocked in range(OCCUPANCY_MAX_SHIFT + 1):
            blocks = (top_cell >> blocked) + 1
            spanned = float(np.prod(blocks.astype(float)))   # in floats: a UTM-wide span overflows int64
            if spanned <= OCCUPANCY_BITS:
                block = coordinates >> blocked
                flat = (block[:, 0] * blocks[1] + block[:, 1]) * blocks[2] + block[:, 2]
                occupied, span, shift = kernels.flag_bits(flat, int(spanned)), blocks, blocked
                break
        return Cells(origin, cell, keys, table, starts, order, np.ascontiguousarray(self.points[order]), occupied, span,
                     shift)
