"""The feature index: exact against a scan, an inverted file against a map, restricted views."""
from contextlib import contextmanager

import numba
import numpy as np
import pytest
from conftest import load_map_query

from regor_ros.core import RegorConfig, kernels, prepare_cloud
from regor_ros.core.feature_index import FeatureIndex


@contextmanager
def numba_threads(count):
    before = numba.get_num_threads()
    numba.set_num_threads(count)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def unit_rows(rng, n):
    f = rng.random((n, 33)).astype(np.float32)
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def test_exact_index_ranks_like_a_full_sort():
    rng = np.random.default_rng(0)
    data, queries = unit_rows(rng, 2000), unit_rows(rng, 50)
    index = FeatureIndex(data, exact_limit=2000, probes=1, nearest_probes=1)
    assert index.exact
    found, similarity = index.search(queries, 10)
    expected = np.argsort(-(queries @ data.T), axis=1)[:, :10]
    np.testing.assert_array_equal(found, expected)
    np.testing.assert_allclose(similarity, np.take_along_axis(queries @ data.T, expected, 1), rtol=1e-5)


def test_the_exact_search_finds_nearest_candidates_and_back_in_one_pass_ties_to_the_lower_row():
    """Small integer features (exact products, many ties, several tiles of queries and rows):
    every query's nearest row, the K candidates of the chosen queries and each row's nearest
    query are those of the full product, equal ones to the lower position, whatever the thread
    count."""
    rng = np.random.default_rng(5)
    data = rng.integers(0, 3, (1500, 33)).astype(np.float32)
    queries = rng.integers(0, 3, (700, 33)).astype(np.float32)
    rows = np.sort(rng.choice(700, 300, replace=False))
    product = queries @ data.T
    index = FeatureIndex(data, exact_limit=1500, probes=1, nearest_probes=1)
    answers = []
    for threads in (1, kernels.threads()):
        with numba_threads(threads):
            answers.append(index.nearest_and_candidates(queries, rows, 20, back=True))
    for a, b in zip(*answers, strict=True):
        np.testing.assert_array_equal(a, b)
    nearest, similarity, candidates, candidate_similarity, back = answers[0]
    np.testing.assert_array_equal(nearest, product.argmax(1))   # argmax: the first of equal ones
    np.testing.assert_array_equal(similarity, product.max(1))
    np.testing.assert_array_equal(back, product.argmax(0))
    ranked = np.array([np.lexsort((np.arange(1500), -row))[:20] for row in product[rows]])
    np.testing.assert_array_equal(candidates, ranked)
    np.testing.assert_array_equal(candidate_similarity, np.take_along_axis(product[rows], ranked, 1))
    assert (candidate_similarity[:, :-1] == candidate_similarity[:, 1:]).sum() > 1000   # ties tested


def test_the_exact_search_refills_a_list_whose_sampled_floor_left_fewer_than_k():
    """The rows that set a list's starting floor (every FLOOR_STRIDE-th) are all the queries'
    best and equal, so the floor is the best similarity and no row passes it: each list is filled
    again from its tile's products, and the K candidates are still the full product's, ties to
    the lower row, the first of them each query's nearest."""
    rng = np.random.default_rng(7)
    data = rng.integers(0, 3, (2000, 33)).astype(np.float32)
    data[::kernels.FLOOR_STRIDE] = 3.0
    queries = rng.integers(0, 3, (300, 33)).astype(np.float32)
    rows = np.arange(0, 300, 3)
    product = queries @ data.T
    nearest, similarity, candidates, candidate_similarity, _ = FeatureIndex(data, 2000, 1, 1).nearest_and_candidates(
        queries, rows, 20)
    np.testing.assert_array_equal(nearest, product.argmax(1))
    np.testing.assert_array_equal(similarity, product.max(1))
    ranked = np.array([np.lexsort((np.arange(2000), -row))[:20] for row in product[rows]])
    np.testing.assert_array_equal(candidates, ranked)
    np.testing.assert_array_equal(candidates[:, :5], np.tile(np.arange(5) * kernels.FLOOR_STRIDE, (len(rows), 1)))
    np.testing.assert_array_equal(candidate_similarity, np.take_along_axis(product[rows], ranked, 1))


def test_a_real_map_index_finds_what_the_exact_search_finds():
    """On a real scan and map (MulRan, OS1-64), the inverted file returns at least 99 % of the
    exact K = 100 candidates (counted by similarity: FPFH has many ties) and of the exact nearest
    neighbours."""
    scan, cloud, _ = load_map_query("scaloam_mulran_kaist03", "scan_000001")
    config = RegorConfig.preset("outdoor")
    source, target = prepare_cloud(scan, config), prepare_cloud(cloud, config, viewpoint=None)
    assert not target.index.exact  # 74 k keypoints: beyond features.exact_search_limit
    exact = FeatureIndex(target.features, len(target), 1, 1)
    queries = source.features[::5]
    approx_sim = target.index.search(queries, 100)[1]
    exact_sim = exact.search(queries, 100)[1]
    assert np.mean(approx_sim >= exact_sim[:, -1:] - 1e-6) >= 0.99
    nearest_sim = target.index.search(queries, 1)[1][:, 0]   # features.search_probes_nearest cells
    assert np.mean(nearest_sim >= exact_sim[:, 0] - 1e-6) >= 0.99


def test_a_restricted_view_only_returns_its_rows_as_positions():
    rng = np.random.default_rng(1)
    data = unit_rows(rng, 20000)
    index = FeatureIndex(data, exact_limit=1000, probes=64, nearest_probes=32)
    assert not index.exact
    rows = np.sort(rng.choice(20000, 5000, replace=False))
    small = index.restricted(rows[:800], data[rows[:800]])   # within the exact limit: a new exact index
    large = index.restricted(rows, data[rows])               # beyond it: the map's cells, filtered
    assert small.exact and len(small) == 800
    assert not large.exact and len(large) == 5000
    for view, count in ((small, 800), (large, 5000)):
        queries = data[rows[:count:4]]                        # each query is one of the view's rows
        found, _ = view.search(queries, 3)
        assert found.min() >= 0 and found.max() < count
        assert np.mean(found[:, 0] == np.arange(0, count, 4)) > 0.95  # a row finds itself


def _faiss_inverted_file(index: FeatureIndex):
    """FAISS's own inverted file over the same cells and lists: the reference scan."""
    import faiss
    centres, cells = index.saved()
    quantizer = faiss.IndexFlatIP(centres.shape[1])
    quantizer.add(centres)
    reference = faiss.IndexIVFFlat(quantizer, centres.shape[1], len(centres), faiss.METRIC_INNER_PRODUCT)
    features = np.ascontiguousarray(index._table().table[np.argsort(index._table().ids)])
    assigned = cells.astype(np.int64)   # both held: swig_ptr does not keep an array alive
    reference.add_core(len(cells), faiss.swig_ptr(features), None, faiss.swig_ptr(assigned))
    return reference


@pytest.mark.parametrize("k", [1, 10])
def test_the_by_cell_scan_finds_what_faiss_finds_in_the_same_cells(k):
    """Nearest neighbours and K candidates come from CellTable's by-cell scan, not FAISS's
    query-by-query scan; over the same probed cells both find the same rows (random features:
    no ties) and similarities to float rounding, for the whole index and a restricted view."""
    import faiss
    rng = np.random.default_rng(2)
    data, queries = unit_rows(rng, 30000), unit_rows(rng, 3000)
    index = FeatureIndex(data, exact_limit=1000, probes=16, nearest_probes=8)
    reference = _faiss_inverted_file(index)
    rows = np.sort(rng.choice(30000, 12000, replace=False))
    view = index.restricted(rows, data[rows])
    member = np.zeros(30000, bool)
    member[rows] = True
    bitmap = np.packbits(member, bitorder="little")
    for searched, ids, selector in ((index, np.arange(30000), None),
                                    (view, rows, faiss.IDSelectorBitmap(30000, faiss.swig_ptr(bitmap)))):
        found, similarity = searched.search(queries, k)
        params = faiss.SearchParametersIVF(nprobe=8 if k == 1 else 16)
        if selector is not None:
            params.sel = selector
        faiss_similarity, faiss_found = reference.search(queries, k, params=params)
        np.testing.assert_allclose(similarity, faiss_similarity, rtol=0, atol=1e-6)
        np.testing.assert_allclose(similarity, np.einsum("qd,qkd->qk", queries, data[ids[found]]), atol=1e-6)
        assert np.mean(ids[found] == faiss_found) > 0.99
        assert (np.diff(similarity, axis=1) <= 0).all()


def test_the_by_cell_scan_breaks_ties_by_row_whatever_the_thread_count():
    """FPFH has many identical histograms; among equally similar rows the lower cell, then the
    lower row, is taken first, and the answer is the same however the cells are split among
    threads."""
    rng = np.random.default_rng(4)
    distinct = unit_rows(rng, 300)
    data = distinct[rng.integers(0, 300, 6000)]          # every feature many times over
    index = FeatureIndex(data, exact_limit=1000, probes=8, nearest_probes=4)
    queries = unit_rows(rng, 400)
    table = index._table()
    probed = table.probed(queries, 8)
    answers = [kernels.cell_top_k(queries, probed, table.table, table.bounds, 20, chunks) for chunks in (1, 2, 5)]
    for position, similarity in answers[1:]:
        np.testing.assert_array_equal(position, answers[0][0])
        np.testing.assert_array_equal(similarity, answers[0][1])
    position, similarity = answers[0]
    tied = similarity[:, :-1] == similarity[:, 1:]
    assert tied.sum() > 100
    assert (position[:, :-1][tied] < position[:, 1:][tied]).all()
    found, _ = index.search(queries, 20)
    np.testing.assert_array_equal(found, table.ids[position])


def brute_top_k(queries, probed, table, bounds, k):
    """The by-cell scan's answer the slow way: every row of each query's probed cells ranked by
    similarity, ties to the lower row; -1 and -inf past the rows there are."""
    positions = np.full((len(queries), k), -1)
    similarities = np.full((len(queries), k), -np.inf, np.float32)
    for q, cells in enumerate(probed):
        rows = np.concatenate([np.arange(bounds[c], bounds[c + 1]) for c in cells])
        dots = table[rows] @ queries[q]
        order = np.lexsort((rows, -dots))[:k]
        positions[q, :len(order)], similarities[q, :len(order)] = rows[order], dots[order]
    return positions, similarities


def test_the_by_cell_scan_s_sampled_floor_keeps_the_exact_answer_where_it_leaves_too_few():
    """Each query's floor is sampled from every 16th row of its cells; where the rows above it are
    fewer than k (probed cells holding fewer rows than k, or a floor that fell too high) the query
    is scanned again without one. Either way the answer is every row ranked (to 1e-6: the scan's
    products run in blocks)."""
    rng = np.random.default_rng(7)
    k = 20
    cell_sizes = np.concatenate([rng.integers(1, 4, 30), rng.integers(40, 120, 10)])   # small cells, then large
    bounds = np.concatenate([[0], np.cumsum(cell_sizes)]).astype(np.int64)
    table = unit_rows(rng, int(bounds[-1]))
    queries = unit_rows(rng, 60)
    few = rng.permuted(np.tile(np.arange(30), (30, 1)), axis=1)[:, :5]     # five small cells: under k rows
    many = rng.permuted(np.tile(np.arange(30, 40), (30, 1)), axis=1)[:, :5]
    probed = np.vstack([few, many]).astype(np.int64)
    position, similarity = kernels.cell_top_k(queries, probed, table, bounds, k, 2)
    expected_position, expected_similarity = brute_top_k(queries, probed, table, bounds, k)
    np.testing.assert_array_equal(position, expected_position)
    np.testing.assert_allclose(similarity, expected_similarity, rtol=0, atol=1e-6)
    assert (position[:30] == -1).any() and (position[30:] >= 0).all()


def test_nearest_and_candidates_takes_a_candidate_row_s_first_only_in_an_inverted_file():
    """Against a scan (exact) every query gets its nearest row as a search for it alone does;
    against an inverted file a query with candidates takes its first as its nearest row, which is
    at least as similar as what the nearest-neighbour scan (fewer cells) finds, and the other
    queries get that scan's answer."""
    rng = np.random.default_rng(3)
    data, queries = unit_rows(rng, 30000), unit_rows(rng, 3000)
    rows = np.sort(rng.choice(3000, 500, replace=False))
    for index in (FeatureIndex(data, exact_limit=30000, probes=32, nearest_probes=8),
                  FeatureIndex(data, exact_limit=1000, probes=32, nearest_probes=8)):
        nearest, similarity, candidates, candidate_similarity, _ = index.nearest_and_candidates(queries, rows, 10)
        scanned, scanned_similarity = (a[:, 0] for a in index.search(queries, 1))
        searched, searched_similarity = index.search(queries[rows], 10)
        np.testing.assert_array_equal(candidates, searched)
        # the same dot products summed in another order (the compiled scan, FAISS): equal up to float32
        # rounding, which depends on the processor's instructions (fused multiply-add or not)
        np.testing.assert_allclose(candidate_similarity, searched_similarity, rtol=1e-6)
        others = np.setdiff1d(np.arange(3000), rows)
        np.testing.assert_array_equal(nearest[others], scanned[others])
        if index.exact:
            np.testing.assert_array_equal(nearest, scanned)
            np.testing.assert_array_equal(similarity, scanned_similarity)
        else:
            np.testing.assert_array_equal(nearest[rows], candidates[:, 0])
            assert (similarity[rows] >= scanned_similarity[rows] - 1e-6).all()   # products of other shapes
            assert (similarity[rows] > scanned_similarity[rows]).any()    # more cells found better


def test_an_inverted_file_saved_and_restored_searches_as_the_trained_one():
    """A cached map keeps the cell centres and each row's cell, not FAISS's serialisation; the
    rows filed again in row order give the same lists, so the same candidates."""
    rng = np.random.default_rng(3)
    features = rng.normal(size=(30000, 33)).astype(np.float32)
    features /= np.linalg.norm(features, axis=1, keepdims=True)
    trained = FeatureIndex(features, 10000, 64, 32)
    centres, cells = trained.saved()
    assert centres.shape[1] == 33 and cells.shape == (30000,)
    restored = FeatureIndex(features, 10000, 64, 32, saved=(centres, cells))
    queries = features[:500] + 0.05 * rng.normal(size=(500, 33)).astype(np.float32)
    for a, b in zip(trained.search(queries, 20), restored.search(queries, 20), strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="saved index"):
        FeatureIndex(features[:20000], 10000, 64, 32, saved=(centres, cells))


def test_an_inverted_file_is_trained_when_first_searched_and_answers_as_one_trained_at_once():
    """A scan's or a fused sequence's index is often never searched (register() searches the
    map's), so its cells are trained only when asked for; a map's are trained before its first
    query (built), and both answer alike."""
    rng = np.random.default_rng(5)
    features = unit_rows(rng, 12000)
    lazy, eager = FeatureIndex(features, 5000, 32, 16), FeatureIndex(features, 5000, 32, 16).built()
    assert lazy._cells is None and eager._cells is not None
    queries = unit_rows(rng, 300)
    for a, b in zip(lazy.search(queries, 10), eager.search(queries, 10), strict=True):
        np.testing.assert_array_equal(a, b)
    assert lazy._cells is not None
    exact = features @ queries.T   # a product of other shapes: the last bit may differ
    chosen = lazy.most_similar(queries)
    assert (exact[chosen, np.arange(300)] >= exact.max(axis=0) - 1e-6).all()
    assert (chosen == exact.argmax(axis=0)).mean() > 0.99


def test_a_map_s_cells_are_trained_in_two_levels_and_rows_filed_in_their_most_similar_cell():
    """The cells of a real map (MulRan, OS1-64) are about CELLS_PER_SQRT sqrt(N), unit centres,
    trained in two levels; a row is filed among its FILING_COARSE nearest coarse cells, which
    holds its most similar cell nearly always; and the same features give the same cells."""
    from regor_ros.core import feature_index
    _, cloud, _ = load_map_query("scaloam_mulran_kaist03", "scan_000001")
    target = prepare_cloud(cloud, RegorConfig.preset("outdoor"), viewpoint=None)
    centres, cells = target.index.saved()
    expected = feature_index.CELLS_PER_SQRT * np.sqrt(len(target))
    assert abs(len(centres) - expected) < 0.05 * expected
    np.testing.assert_allclose(np.linalg.norm(centres, axis=1), 1.0, atol=1e-5)
    most_similar = np.argmax(target.features.astype(np.float32) @ centres.T, axis=1)
    assert np.mean(cells == most_similar) > 0.9
    again = FeatureIndex(target.features, 1000, 8, 4).saved()
    np.testing.assert_array_equal(again[0], centres)
    np.testing.assert_array_equal(again[1], cells)
