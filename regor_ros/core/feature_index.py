"""Search over one cloud's FPFH features, built once with the cloud.

Matching asks, for every source keypoint, its most similar target keypoint, and for a few
thousand of them the K most similar; the outdoor preset also asks each target keypoint's most
similar source keypoint (mutual matches). Against a scan-sized target an exact search is
affordable and is what runs: one compiled pass over the products (``kernels.flat_search``)
answers all three, where FAISS searched three times. Against a map it is not: the dense
similarity grows with the map, so beyond
``exact_limit`` keypoints the features go into an inverted-file index (k-means cells, seeded,
so the same map gives the same index) and a query scans only the cells nearest to it
(features.search_probes, search_probes_nearest: how many).

A query scans its probed cells for its nearest neighbour (every scan keypoint, about 14 k) and
for its K candidates (a few thousand of them). FAISS scans query by query, so each query streams
its cells' rows from memory again; ``CellTable``
turns the loop around: each cell's rows are read once, in one matrix product with all the
queries that probe it (``kernels.cell_top_k``, compiled, on every thread). The probed cells and
the rows compared are FAISS's; the similarities are the matrix product's (FAISS sums in another
order: the last bit may differ), and ties (FPFH has many: identical histograms) go to the lower
cell, then the lower row.

Features are unit vectors: inner product ranks them as the feature distance does.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager

import faiss
import numpy as np

from . import kernels

CELLS_PER_SQRT = 4        # k-means cells = 4 sqrt(n), FAISS's rule of thumb for inverted files
MIN_ROWS_PER_CELL = 40    # k-means needs about 40 training rows per cell
TRAINING_PER_CELL = 64    # training sample per cell (all rows if fewer)
KMEANS_SEED = 1234
KMEANS_ITERATIONS = 10    # FAISS's own for an inverted file's cells
FILING_COARSE = 2         # coarse cells a row's own cell is looked for in
FILING_BLOCK = 1 << 15    # rows filed at a time


@contextmanager
def _reservoir_top_k():
    """FAISS's flat search keeps each query's top k in a heap for k < 100 and in a reservoir
    (collect, then partition) from 100 on. For the probed cells of thousands of queries (k = 64
    of a few thousand cells) the reservoir gives the same cells in the same order, sooner.
    FAISS's switch is process-wide, so it is restored on the way out."""
    before = faiss.cvar.distance_compute_min_k_reservoir
    faiss.cvar.distance_compute_min_k_reservoir = 1
    try:
        yield
    finally:
        faiss.cvar.distance_compute_min_k_reservoir = before


class CellTable:
    """An inverted file: k-means cell centres (a FAISS flat index, which finds the cells a query
    probes: a scan by query, the centres fit in cache) and the rows filed by cell, for the by-cell
    scan."""

    def __init__(self, quantizer, ids: np.ndarray, table: np.ndarray, bounds: np.ndarray):
        self.quantizer = quantizer  # FAISS flat index over the cell centres
        self.ids = ids              # (M,) the index row each table row is, cell by cell
        self.table = table          # (M, D) float32 the rows' features, cell by cell
        self.bounds = bounds        # (cells + 1,) cell c holds table rows bounds[c]:bounds[c + 1]

    @property
    def cells(self) -> int:
        """How many cells the index has."""
        return len(self.bounds) - 1

    @classmethod
    def filed(cls, quantizer, features: np.ndarray, cells: np.ndarray) -> CellTable:
        """Each row of ``features`` filed into its cell (rows of a cell in row order)."""
        ids = np.argsort(cells, kind="stable")
        bounds = np.concatenate([[0], np.cumsum(np.bincount(cells, minlength=quantizer.ntotal))])
        return cls(quantizer, ids, features[ids], bounds.astype(np.int64))

    def _cell_of_table_row(self) -> np.ndarray:
        return np.repeat(np.arange(self.cells, dtype=np.int32), np.diff(self.bounds))

    def cell_of_each_row(self) -> np.ndarray:
        """(N,) the cell each index row is filed in (what a cache keeps)."""
        cells = np.empty(len(self.ids), np.int32)
        cells[self.ids] = self._cell_of_table_row()
        return cells

    def subset(self, rows: np.ndarray) -> CellTable:
        """The table of ``rows`` (sorted) alone, in the same cells, numbered by position in ``rows``."""
        member = np.zeros(len(self.ids), dtype=bool)
        member[rows] = True
        keep = member[self.ids]
        counts = np.bincount(self._cell_of_table_row()[keep], minlength=self.cells)
        return CellTable(self.quantizer, np.searchsorted(rows, self.ids[keep]),
                         self.table[keep],
                         np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))

    def search(self, queries: np.ndarray, k: int, probes: int) -> tuple[np.ndarray, np.ndarray]:
        """The k most similar rows among each query's ``probes`` nearest cells: (ids (Q, k), -1
        where fewer were found; similarities (Q, k), -inf there), most similar first. The kernel's
        products run on its threads, so BLAS is kept to one (a registration already does that)."""
        with kernels.blas_on_one_thread():
            position, similarity = kernels.cell_top_k(queries, self.probed(queries, probes), self.table,
                                                      self.bounds, k, kernels.threads())
        return np.where(position >= 0, self.ids[np.maximum(position, 0)], -1), similarity

    def probed(self, queries: np.ndarray, probes: int) -> np.ndarray:
        """(Q, probes) the cells whose centres are most similar to each query."""
        with _reservoir_top_k():
            return self.quantizer.search(queries, min(probes, self.cells))[1]


class FeatureIndex:
    """Inner-product search over (N, D) unit features: exact up to ``exact_limit`` rows (FAISS),
    an inverted file beyond (``CellTable``), scanning ``probes`` cells per query for K candidates
    and ``nearest_probes`` for a nearest neighbour alone (the first is found in fewer cells than
    the hundredth)."""

    def __init__(self, features: np.ndarray, exact_limit: int, probes: int, nearest_probes: int,
                 saved: tuple[np.ndarray, np.ndarray] | None = None):
        """``saved``: what ``saved()`` returned for these features and limits (a cached map's
        trained inverted file, restored instead of trained again). An inverted file is trained
        when first searched (``built``): a scan's or a fused sequence's is often never searched."""
        features = np.ascontiguousarray(features, dtype=np.float32)
        n, dim = features.shape
        self.size = n
        self.exact = n <= exact_limit
        self._limits = (exact_limit, probes, nearest_probes)
        self._features = features
        self._cells: CellTable | None = None
        self._lock = threading.Lock()
        if not self.exact and saved is not None and len(saved[0]):
            self._cells = _restored(features, *saved)

    def __len__(self) -> int:
        return self.size

    def built(self) -> FeatureIndex:
        """This index, its inverted file trained now (a map's, before its first query)."""
        if not self.exact:
            self._table()
        return self

    def saved(self) -> tuple[np.ndarray, np.ndarray]:
        """The trained inverted file without the features it files: (its cell centres (C, D),
        each row's cell (N,)); both empty for an exact index (rebuilt in no time)."""
        if self.exact:
            return np.zeros((0, self._features.shape[1]), np.float32), np.zeros(0, np.int32)
        quantizer = self._table().quantizer
        return quantizer.reconstruct_n(0, quantizer.ntotal), self._table().cell_of_each_row()

    def _table(self) -> CellTable:
        """The inverted file of an approximate index, trained the first time it is asked for."""
        if self.exact:
            raise ValueError("an exact feature index has no cells")
        with self._lock:
            if self._cells is None:
                self._cells = _trained(self._features)
            return self._cells

    def restricted(self, rows: np.ndarray, features: np.ndarray) -> FeatureIndex:
        """An index over ``rows`` (sorted) of this one, whose results are positions in ``rows``;
        ``features`` are those rows' features. Up to the exact limit a new exact index (its cost
        follows the rows); beyond it this index's own cells, filtered to the rows (no new
        training per call)."""
        if len(rows) <= self._limits[0]:  # also whenever this index is exact: rows <= its size
            return FeatureIndex(features, *self._limits)
        view = object.__new__(FeatureIndex)
        view.size, view.exact, view._limits, view._features = len(rows), False, self._limits, features
        view._cells, view._lock = self._table().subset(np.asarray(rows, dtype=np.int64)), threading.Lock()
        return view

    def nearest_and_candidates(self, queries: np.ndarray, rows: np.ndarray, k: int, back: bool = False):
        """Every query's most similar row, and the k most similar of the queries in ``rows``:
        (nearest (Q,), its similarity (Q,), candidates (R, k), their similarities (R, k), back), as
        ``search`` gives them. With ``back``, an exact index also gives each of its rows' most
        similar query (N,), from the same products; ``back`` is None otherwise (an inverted file:
        ask the queries' own index). In an inverted file a query of ``rows`` needs no second
        search: its first candidate is its nearest row, found in more cells than the
        nearest-neighbour scan probes (a sixth of a scan's queries on the outdoor preset)."""
        queries = np.ascontiguousarray(queries, dtype=np.float32)
        if self.exact:
            slot = np.full(len(queries), -1, dtype=np.int64)
            slot[rows] = np.arange(len(rows))
            nearest, best, candidates, similarity, row_query, _ = self._exact(queries, slot, k, back)
            return nearest, best, candidates, similarity, row_query if back else None
        candidates, similarity = self.search(queries[rows], k)
        nearest = np.full(len(queries), -1, dtype=np.int64)
        best = np.full(len(queries), -np.inf, dtype=np.float32)
        nearest[rows], best[rows] = candidates[:, 0], similarity[:, 0]
        rest = np.setdiff1d(np.arange(len(queries)), rows, assume_unique=True)
        found, found_similarity = self.search(queries[rest], 1)
        nearest[rest], best[rest] = found[:, 0], found_similarity[:, 0]
        return nearest, best, candidates, similarity, None

    def search(self, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The k most similar rows of each query, most similar first: (index (Q, k) int64,
        similarity (Q, k) float32). An inverted file may find fewer than k (index -1, similarity
        -inf) when the probed cells hold fewer rows."""
        k = min(k, self.size)
        queries = np.ascontiguousarray(queries, dtype=np.float32)
        if len(queries) == 0:
            return np.zeros((0, k), np.int64), np.zeros((0, k), np.float32)
        if self.exact:
            slot = np.arange(len(queries)) if k > 1 else np.full(len(queries), -1, dtype=np.int64)
            nearest, best, candidates, similarity, _, _ = self._exact(queries, slot, k, False)
            return (candidates, similarity) if k > 1 else (nearest[:, None], best[:, None])
        _, probes, nearest_probes = self._limits
        return self._table().search(queries, k, nearest_probes if k == 1 else probes)

    def most_similar(self, queries: np.ndarray) -> np.ndarray:
        """Each query's most similar row (Q,), by an exact pass over every row whatever kind of
        index this is: a few thousand queries (the targets a mutual check asks about) against a
        scan-sized cloud cost less than training and probing its cells."""
        queries = np.ascontiguousarray(queries, dtype=np.float32)
        return self._exact(queries, np.full(len(queries), -1, dtype=np.int64), 1, False)[0]

    def _exact(self, queries: np.ndarray, slot: np.ndarray, k: int, back: bool):
        """``kernels.flat_search`` over this index's rows, BLAS kept to one thread (the kernel's
        products run on its own threads)."""
        with kernels.blas_on_one_thread():
            return kernels.flat_search(queries, self._features, slot, min(k, self.size), back, kernels.threads())


def _trained(features: np.ndarray) -> CellTable:
    """k-means cells for the features, each row filed into the most similar of them.

    Flat k-means over C cells costs a training sample of TRAINING_PER_CELL C rows times C centres
    per iteration, and filing every row costs N times C: beyond a few hundred thousand keypoints most
    of a map's preparation. So the cells are trained in two levels: about sqrt(C) coarse cells,
    then each coarse cell's training rows split into its share of the C cells. A row is filed
    into the most similar cell of its FILING_COARSE most similar coarse cells, and a query probes
    the most similar cells among all of them. Spherical k-means (unit centres), since similarity
    is the inner product of unit features; FAISS's, seeded, so the same map gives the same cells."""
    n, dim = features.shape
    cells = max(1, min(int(round(CELLS_PER_SQRT * np.sqrt(n))), n // MIN_ROWS_PER_CELL))
    sample = min(n, TRAINING_PER_CELL * cells)
    training = features[np.sort(np.random.default_rng(KMEANS_SEED).choice(n, sample, replace=False))]
    coarse = _kmeans(training, int(round(np.sqrt(cells))), KMEANS_SEED)
    owner = np.argmax(training @ coarse.T, axis=1)   # each sample row's coarse cell
    centres, of_coarse = [], []
    for group in range(len(coarse)):
        rows = training[owner == group]
        count = min(max(1, int(round(cells * len(rows) / sample))), max(1, len(rows) // MIN_ROWS_PER_CELL))
        centres.append(_kmeans(rows, count, KMEANS_SEED + 1 + group) if len(rows) else coarse[group][None])
        of_coarse.append(np.full(len(centres[-1]), group))
    fine = np.ascontiguousarray(np.concatenate(centres), dtype=np.float32)
    quantizer = faiss.IndexFlatIP(dim)
    quantizer.add(fine)
    return CellTable.filed(quantizer, features, _filed(features, coarse, fine, np.concatenate(of_coarse)))


def _kmeans(rows: np.ndarray, count: int, seed: int) -> np.ndarray:
    """``count`` unit centres of ``rows`` (fewer rows than that: the rows themselves)."""
    if len(rows) <= count:
        return np.ascontiguousarray(rows, dtype=np.float32)
    if count == 1:
        mean = rows.mean(axis=0)
        return (mean / max(float(np.linalg.norm(mean)), 1e-12))[None].astype(np.float32)
    kmeans = faiss.Kmeans(rows.shape[1], count, niter=KMEANS_ITERATIONS, seed=seed, spherical=True)
    kmeans.train(np.ascontiguousarray(rows, dtype=np.float32))
    return np.asarray(kmeans.centroids)


def _filed(features: np.ndarray, coarse: np.ndarray, fine: np.ndarray, of_coarse: np.ndarray) -> np.ndarray:
    """(N,) each row's cell: the most similar fine centre among those of its FILING_COARSE most
    similar coarse cells, a block of rows at a time (the products of every row with every coarse
    centre at once would be the map's size times theirs)."""
    members = [np.flatnonzero(of_coarse == group) for group in range(len(coarse))]
    nearest = min(FILING_COARSE, len(coarse))
    cells = np.empty(len(features), dtype=np.int64)
    for start in range(0, len(features), FILING_BLOCK):
        block = features[start:start + FILING_BLOCK]
        similarity = block @ coarse.T
        near = np.empty((len(block), nearest), dtype=np.int64)
        for k in range(nearest):   # the k-th most similar coarse cell, ties to the lower one
            near[:, k] = np.argmax(similarity, axis=1)
            similarity[np.arange(len(block)), near[:, k]] = -np.inf
        # the (row, coarse cell) pairs grouped by cell, rows in order within each
        pair_row = np.repeat(np.arange(len(block)), nearest)[np.argsort(near.ravel(), kind="stable")]
        bounds = np.concatenate([[0], np.cumsum(np.bincount(near.ravel(), minlength=len(coarse)))])
        best = np.full(len(block), -np.inf, dtype=np.float32)
        cell = cells[start:start + FILING_BLOCK]
        for group in range(len(coarse)):
            rows = pair_row[bounds[group]:bounds[group + 1]]
            if not len(rows):
                continue
            fine_similarity = block[rows] @ fine[members[group]].T
            pick = np.argmax(fine_similarity, axis=1)
            value = fine_similarity[np.arange(len(rows)), pick]
            better = value > best[rows]   # groups in order, so a tie keeps the lower cell
            best[rows[better]], cell[rows[better]] = value[better], members[group][pick[better]]
    return cells


def _restored(features: np.ndarray, centres: np.ndarray, cells: np.ndarray) -> CellTable:
    """The inverted file ``saved()`` described: the rows filed into the cells they were in."""
    n, dim = features.shape
    if centres.ndim != 2 or centres.shape[1] != dim or cells.shape != (n,) or not len(centres) \
            or cells.min() < 0 or cells.max() >= len(centres):
        raise ValueError(f"the saved index has {centres.shape} cell centres and {cells.shape} cells, "
                         f"not for {n} rows of {dim}")
    quantizer = faiss.IndexFlatIP(dim)
    quantizer.add(np.ascontiguousarray(centres, dtype=np.float32))
    return CellTable.filed(quantizer, features, np.asarray(cells, dtype=np.int64))
