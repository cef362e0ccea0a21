"""Search over one cloud's FPFH features, built once with the cloud (FAISS).

Matching asks, for every source keypoint, its most similar target keypoint, and for a few
thousand of them the K most similar. Against a scan-sized target an exact search is affordable
and is what runs. Against a map it is not: the dense similarity grows with the map (98 s and
11 GB against 634 k keypoints), so beyond ``exact_limit`` keypoints the features go into an
inverted-file index (k-means cells, seeded, so the same map gives the same index) and a query
scans only the cells nearest to it. Measured on the real scan-to-map data (MulRan, OS1-64, 74 k
map keypoints), 128 cells return 99.8 % of the exact K = 100 candidates (by similarity) and 64
cells 99.8 % of the exact nearest neighbours (99.97 % with 128, at twice the time).

Features are unit vectors: inner product ranks them as the feature distance does.
"""
from __future__ import annotations

from typing import Optional, Tuple

import faiss
import numpy as np

CELLS_PER_SQRT = 4        # k-means cells = 4 sqrt(n), FAISS's rule of thumb for inverted files
MIN_ROWS_PER_CELL = 40    # k-means needs about 40 training rows per cell
TRAINING_PER_CELL = 64    # training sample per cell (all rows if fewer)
KMEANS_SEED = 1234


class FeatureIndex:
    """Inner-product search over (N, D) unit features: exact up to ``exact_limit`` rows, an
    inverted file beyond, scanning ``probes`` cells per query for K candidates and
    ``nearest_probes`` for a nearest neighbour alone (the first is found in fewer cells than the
    hundredth)."""

    def __init__(self, features: np.ndarray, exact_limit: int, probes: int, nearest_probes: int):
        features = np.ascontiguousarray(features, dtype=np.float32)
        n, dim = features.shape
        self.size = n
        self.exact = n <= exact_limit
        self._limits = (exact_limit, probes, nearest_probes)
        self._rows: Optional[np.ndarray] = None  # a restricted view: the parent's rows it searches
        self._selector = None
        if self.exact:
            self._index = faiss.IndexFlatIP(dim)
        else:
            cells = max(1, min(int(round(CELLS_PER_SQRT * np.sqrt(n))), n // MIN_ROWS_PER_CELL))
            self._index = faiss.IndexIVFFlat(faiss.IndexFlatIP(dim), dim, cells,
                                             faiss.METRIC_INNER_PRODUCT)
            self._index.cp.seed = KMEANS_SEED
            sample = min(n, TRAINING_PER_CELL * cells)
            rows = np.random.default_rng(KMEANS_SEED).choice(n, sample, replace=False) if sample < n else slice(None)
            self._index.train(features[rows])
        self._index.add(features)

    def __len__(self) -> int:
        return self.size

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
        return view

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
        params = faiss.SearchParametersIVF(nprobe=nearest_probes if k == 1 else probes)
        if self._selector is not None:
            params.sel = self._selector
        similarity, index = self._index.search(queries, k, params=params)
        if self._rows is not None:
            found = index >= 0
            index[found] = np.searchsorted(self._rows, index[found])
        return index.astype(np.int64), similarity
