"""Kernels of the feature search (core/feature_index.py): the inverted file's by-cell scan
(CellTable) and the exact search's tiled products, each keeping its top k."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .common import _kth_smallest, _largest
from .threads import JIT

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
