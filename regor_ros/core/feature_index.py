"""Search over one cloud's FPFH features, built once with the cloud (FAISS).

Matching asks, for every source keypoint, its most similar target keypoint, and for a few
thousand of them the K most similar. Against a scan-sized target an exact search is affordable
and is what runs. Against a map it is not: the dense similarity grows with the map (98 s and
11 GB against 634 k keypoints), so beyond ``exact_limit`` keypoints the features go into an
inverted-file index (k-means cells, seeded, so the same map gives the same index) and a query
scans only the cells nearest to it. Measured on the real scan-to-map data (MulRan, OS1-64, 74 k
map keypoints), 128 cells return 99.8 % of the exact K = 100 candidates (by similarity) and 64
cells 99.8 % of the exact nearest neighbours (99.97 % with 128, at twice the time).

A nearest neighbour for every scan keypoint (about 14 k) is most of the work against a map.
FAISS scans the probed cells query by query, so each query streams its cells' rows from memory;
``CellTable`` turns the loop around: for each cell, all queries that probe it are compared with
its rows in one matrix product, and each query keeps the best it has seen. The probed cells and
the rows compared are the same as FAISS's, so the nearest neighbours are too (up to ties); on a
582 k-keypoint map the scan took 0.50 s instead of 1.26 s.

Features are unit vectors: inner product ranks them as the feature distance does.
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import List, Optional, Tuple

import faiss
import numpy as np

CELLS_PER_SQRT = 4        # k-means cells = 4 sqrt(n), FAISS's rule of thumb for inverted files
MIN_ROWS_PER_CELL = 40    # k-means needs about 40 training rows per cell
TRAINING_PER_CELL = 64    # training sample per cell (all rows if fewer)
KMEANS_SEED = 1234


@contextmanager
def _reservoir_top_k():
    """FAISS's flat search keeps each query's top k in a heap for k < 100 and in a reservoir
    (collect, then partition) from 100 on. For the probed cells of thousands of queries (k = 64
    of a few thousand cells) the reservoir gives the same cells in the same order in 0.09 s
    instead of 0.12 s (506 k-keypoint map, 14.5 k queries). FAISS's switch is process-wide,
    so it is restored on the way out."""
    before = faiss.cvar.distance_compute_min_k_reservoir
    faiss.cvar.distance_compute_min_k_reservoir = 1
    try:
        yield
    finally:
        faiss.cvar.distance_compute_min_k_reservoir = before


class CellTable:
    """An inverted file's rows grouped by cell, for a by-cell nearest-neighbour scan. A full
    table's feature blocks are views of FAISS's own lists (an IVF-Flat list stores its rows'
    features as they are): no second copy of a map's features (77 MB at 582 k rows)."""

    def __init__(self, quantizer, ids: np.ndarray, blocks: List[np.ndarray], bounds: np.ndarray, owner=None):
        self.quantizer = quantizer  # FAISS index over the cell centres: which cells a query probes
        self.ids = ids              # (M,) index rows, cell by cell
        self.blocks = blocks        # per cell, (rows in it, D) their features
        self.bounds = bounds        # (cells + 1,) cell c holds rows bounds[c]:bounds[c + 1]
        self._owner = owner         # the inverted file whose memory the blocks view

    @property
    def cells(self) -> int:
        return len(self.bounds) - 1

    @classmethod
    def of(cls, ivf) -> "CellTable":
        """The layout of a filled FAISS inverted file (its cells, in its order)."""
        lists, dim = ivf.invlists, ivf.d
        sizes = np.array([lists.list_size(c) for c in range(ivf.nlist)], dtype=np.int64)
        ids = np.concatenate([faiss.rev_swig_ptr(lists.get_ids(c), int(sizes[c])).copy()
                              for c in range(ivf.nlist) if sizes[c]] or [np.zeros(0, np.int64)])
        blocks = [faiss.rev_swig_ptr(lists.get_codes(c), int(size) * dim * 4).view(np.float32).reshape(-1, dim)
                  if size else np.zeros((0, dim), np.float32) for c, size in enumerate(sizes)]
        return cls(ivf.quantizer, ids, blocks, np.concatenate([[0], np.cumsum(sizes)]), ivf)

    def subset(self, member: np.ndarray) -> "CellTable":
        """The table of the rows whose ``member`` flag is set, in the same cells (copied)."""
        keep = member[self.ids]
        blocks = [block[keep[self.bounds[c]:self.bounds[c + 1]]] for c, block in enumerate(self.blocks)]
        return CellTable(self.quantizer, self.ids[keep], blocks,
                         np.concatenate([[0], np.cumsum([len(b) for b in blocks])]))

    def nearest(self, queries: np.ndarray, probes: int) -> Tuple[np.ndarray, np.ndarray]:
        """The most similar row among each query's probed cells: (ids (Q,), -1 when none;
        similarity (Q,), -inf when none). Ties go to the lower cell, then the lower id."""
        with _reservoir_top_k():
            probed = self.quantizer.search(queries, min(probes, self.cells))[1]
        cell = probed.ravel()
        # group the (query, cell) pairs by cell; 16-bit keys sort by radix, five times faster
        order = np.argsort(cell.astype(np.uint16) if self.cells <= 1 << 16 else cell, kind="stable")
        query, cell = order // probed.shape[1], cell[order]
        starts = np.searchsorted(cell, np.arange(self.cells + 1))
        best = np.full(len(queries), -np.inf, dtype=np.float32)
        found = np.full(len(queries), -1, dtype=np.int64)
        for c in np.flatnonzero((np.diff(starts) > 0) & (np.diff(self.bounds) > 0)):
            asking = query[starts[c]:starts[c + 1]]
            similarity = queries[asking] @ self.blocks[c].T
            column = similarity.argmax(axis=1)
            value = similarity[np.arange(len(asking)), column]
            better = value > best[asking]
            best[asking[better]] = value[better]
            found[asking[better]] = self.ids[self.bounds[c] + column[better]]
        return found, best


def _refiled(features: np.ndarray, centres: np.ndarray, cells: np.ndarray) -> faiss.IndexIVFFlat:
    """The inverted file ``saved()`` described: the rows filed in row order into the cells they
    were in, so each cell's list is the one training and adding built."""
    n, dim = features.shape
    if centres.ndim != 2 or centres.shape[1] != dim or cells.shape != (n,) or not len(centres) \
            or cells.min() < 0 or cells.max() >= len(centres):
        raise ValueError(f"the saved index has {centres.shape} cell centres and {cells.shape} cells, "
                         f"not for {n} rows of {dim}")
    quantizer = faiss.IndexFlatIP(dim)
    quantizer.add(np.ascontiguousarray(centres, dtype=np.float32))
    index = faiss.IndexIVFFlat(quantizer, dim, len(centres), faiss.METRIC_INNER_PRODUCT)
    assigned = np.ascontiguousarray(cells, dtype=np.int64)   # held: swig_ptr does not keep it alive
    index.add_core(n, faiss.swig_ptr(features), None, faiss.swig_ptr(assigned))
    return index


class FeatureIndex:
    """Inner-product search over (N, D) unit features: exact up to ``exact_limit`` rows, an
    inverted file beyond, scanning ``probes`` cells per query for K candidates (FAISS) and
    ``nearest_probes`` for a nearest neighbour alone (the first is found in fewer cells than the
    hundredth; by cell, ``CellTable``)."""

    def __init__(self, features: np.ndarray, exact_limit: int, probes: int, nearest_probes: int,
                 saved: Optional[Tuple[np.ndarray, np.ndarray]] = None):
        """``saved``: what ``saved()`` returned for these features and limits (a cached map's
        trained inverted file, restored instead of trained again)."""
        features = np.ascontiguousarray(features, dtype=np.float32)
        n, dim = features.shape
        self.size = n
        self.exact = n <= exact_limit
        self._limits = (exact_limit, probes, nearest_probes)
        self._rows: Optional[np.ndarray] = None  # a restricted view: the parent's rows it searches
        self._selector = None
        self._cells: Optional[CellTable] = None
        if self.exact:
            self._index = faiss.IndexFlatIP(dim)
        elif saved is not None and len(saved[0]):
            self._index = _refiled(features, *saved)
        else:
            cells = max(1, min(int(round(CELLS_PER_SQRT * np.sqrt(n))), n // MIN_ROWS_PER_CELL))
            self._index = faiss.IndexIVFFlat(faiss.IndexFlatIP(dim), dim, cells,
                                             faiss.METRIC_INNER_PRODUCT)
            self._index.cp.seed = KMEANS_SEED
            sample = min(n, TRAINING_PER_CELL * cells)
            rows = np.random.default_rng(KMEANS_SEED).choice(n, sample, replace=False) if sample < n else slice(None)
            self._index.train(features[rows])
        if self._index.ntotal == 0:
            self._index.add(features)
        if not self.exact:
            self._cells = CellTable.of(self._index)

    def __len__(self) -> int:
        return self.size

    def saved(self) -> Tuple[np.ndarray, np.ndarray]:
        """The trained inverted file without the features it files: (its cell centres (C, D),
        each row's cell (N,)); both empty for an exact index (rebuilt in no time). FAISS's own
        serialisation copies every feature twice more on the way out (0.16 GB at 582 k rows)."""
        if self.exact:
            return np.zeros((0, self._index.d), np.float32), np.zeros(0, np.int32)
        cells = np.empty(self.size, np.int32)
        cells[self._cells.ids] = np.repeat(np.arange(self._cells.cells, dtype=np.int32), np.diff(self._cells.bounds))
        return self._index.quantizer.reconstruct_n(0, self._index.nlist), cells

    def restricted(self, rows: np.ndarray, features: np.ndarray) -> "FeatureIndex":
        """An index over ``rows`` (sorted) of this one, whose results are positions in ``rows``;
        ``features`` are those rows' features. Up to the exact limit a new exact index (its cost
        follows the rows); beyond it this index's own cells, filtered to the rows (no new
        training per call)."""
        if len(rows) <= self._limits[0]:  # also whenever this index is exact: rows <= its size
            return FeatureIndex(features, *self._limits)
        view = object.__new__(FeatureIndex)
        view.size, view.exact, view._limits, view._index = len(rows), False, self._limits, self._index
        view._rows = np.ascontiguousarray(rows, dtype=np.int64)
        member = np.zeros(self.size, dtype=bool)
        member[view._rows] = True
        view._bitmap = np.packbits(member, bitorder="little")  # kept alive for the selector
        view._selector = faiss.IDSelectorBitmap(self.size, faiss.swig_ptr(view._bitmap))
        view._cells = self._cells.subset(member)
        return view

    def nearest_and_candidates(self, queries: np.ndarray, rows: np.ndarray, k: int):
        """Every query's most similar row, and the k most similar of the queries in ``rows``:
        (nearest (Q,), its similarity (Q,), candidates (R, k), their similarities (R, k)), as
        ``search`` gives them. In an inverted file, a query of ``rows`` whose candidates have a
        unique best needs no second search: that is its nearest row, found in more cells than the
        nearest-neighbour scan probes (a sixth of a scan's queries on the outdoor preset)."""
        queries = np.ascontiguousarray(queries, dtype=np.float32)
        candidates, similarity = self.search(queries[rows], k)
        rest = np.arange(len(queries))
        nearest = np.full(len(queries), -1, dtype=np.int64)
        best = np.full(len(queries), -np.inf, dtype=np.float32)
        if not self.exact and candidates.shape[1] > 1:
            unique = similarity[:, 0] > similarity[:, 1]
            nearest[rows[unique]], best[rows[unique]] = candidates[unique, 0], similarity[unique, 0]
            rest = np.setdiff1d(rest, rows[unique], assume_unique=True)
        found, found_similarity = self.search(queries[rest], 1)
        nearest[rest], best[rest] = found[:, 0], found_similarity[:, 0]
        return nearest, best, candidates, similarity

    def search(self, queries: np.ndarray, k: int) -> Tuple[np.ndarray, np.ndarray]:
        """The k most similar rows of each query, most similar first: (index (Q, k) int64,
        similarity (Q, k) float32). An inverted file may find fewer than k (index -1, similarity
        -inf) when the probed cells hold fewer rows."""
        k = min(k, self.size)
        queries = np.ascontiguousarray(queries, dtype=np.float32)
        if len(queries) == 0:
            return np.zeros((0, k), np.int64), np.zeros((0, k), np.float32)
        if self.exact:
            similarity, index = self._index.search(queries, k)
            return index.astype(np.int64), similarity
        _, probes, nearest_probes = self._limits
        if k == 1:
            index, similarity = (a[:, None] for a in self._cells.nearest(queries, nearest_probes))
        else:
            params = faiss.SearchParametersIVF(nprobe=probes)
            if self._selector is not None:
                params.sel = self._selector
            similarity, index = self._index.search(queries, k, params=params)
        if self._rows is not None:
            found = index >= 0
            index[found] = np.searchsorted(self._rows, index[found])
        return index.astype(np.int64), similarity
