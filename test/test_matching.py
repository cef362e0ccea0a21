from types import SimpleNamespace

import numpy as np

from regor_ros.core.feature_index import FeatureIndex
from regor_ros.core.matching import feature_distance, generalized_mutual_matches, match_features


def unit_rows(rng, n):
    f = rng.random((n, 33)).astype(np.float32)
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def cloud(features):
    """What matching reads of a prepared cloud: its features and their exact index."""
    return SimpleNamespace(features=features, index=FeatureIndex(features, len(features), 1, 1))


def top_mask(similarity, k, axis):
    """The k largest along ``axis`` by a stable sort (ties to the lower index): the reference."""
    order = np.argsort(-similarity, axis=axis, kind="stable")
    mask = np.zeros(similarity.shape, dtype=bool)
    np.put_along_axis(mask, np.take(order, np.arange(min(k, similarity.shape[axis])), axis=axis), True, axis=axis)
    return mask


def gmm_mask(similarity, k):
    """generalized_mutual_matches' pairs as a mask over the similarities."""
    rows, cols, count = generalized_mutual_matches(similarity, k)
    mask = np.zeros(similarity.shape, dtype=bool)
    for region, n in enumerate(count):
        assert (rows[region, n:] == -1).all() and (cols[region, n:] == -1).all()
        assert (np.diff(rows[region, :n] * similarity.shape[2] + cols[region, :n]) > 0).all()  # row-major
        mask[region, rows[region, :n], cols[region, :n]] = True
    return mask


def reference_gmm(similarity, k):
    return ((top_mask(similarity, 1, -1) & top_mask(similarity, k, -2))
            | (top_mask(similarity, k, -1) & top_mask(similarity, 1, -2)))


def test_gmm_is_the_sorted_definition_ties_included():
    rng = np.random.default_rng(0)
    for shape in [(20, 30, 30), (7, 12, 5), (3, 4, 9)]:
        sim = rng.random(shape).astype(np.float32)
        sim[:, ::3] = np.round(sim[:, ::3], 1)  # ties, within rows and columns
        for k in (1, 3, 5):
            np.testing.assert_array_equal(gmm_mask(sim, k), reference_gmm(sim, k))


def test_gmm_contains_mutual_matches_and_at_most_two_pairs_per_point():
    rng = np.random.default_rng(0)
    sim = rng.random((20, 30, 30)).astype(np.float32)
    mutual = gmm_mask(sim, 1)
    gmm = gmm_mask(sim, 3)
    assert (gmm | mutual == gmm).all()
    assert gmm.sum() > mutual.sum()
    assert (gmm.sum(axis=(1, 2)) <= 2 * 30).all()


def test_gmm_finds_a_pair_that_mutual_misses():
    # row 0's nearest is column 0, but column 0's nearest is row 1; row 0 is column 0's second
    sim = np.array([[[0.9, 0.1, 0.0], [0.95, 0.2, 0.1], [0.3, 0.2, 0.8]]])
    assert not gmm_mask(sim, 1)[0, 0, 0]
    assert gmm_mask(sim, 3)[0, 0, 0]


def test_match_features_nearest_and_candidates_agree_with_a_full_sort():
    rng = np.random.default_rng(2)
    fs, ft = unit_rows(rng, 300), unit_rows(rng, 500)
    rows = np.arange(0, 300, 3)
    m = match_features(cloud(fs), cloud(ft), candidates=10, candidate_rows=rows)
    sim = fs @ ft.T
    np.testing.assert_array_equal(m.target_index, sim.argmax(axis=1))
    expected = np.sort(np.argsort(-sim[rows], axis=1)[:, :10], axis=1)
    np.testing.assert_array_equal(np.sort(m.candidates, axis=1), expected)
    np.testing.assert_allclose(m.candidate_distance,
                               feature_distance(np.take_along_axis(sim[rows], m.candidates, 1)),
                               atol=1e-6)


def test_feature_distance_of_identical_unit_vectors_is_near_zero():
    assert feature_distance(np.float32(1.0)) < 1e-2
    assert abs(feature_distance(np.float32(-1.0)) - 2.0) < 1e-3


def test_mutual_flags_and_similarities_agree_with_the_full_matrix():
    rng = np.random.default_rng(3)
    fs, ft = unit_rows(rng, 5000), unit_rows(rng, 300)
    m = match_features(cloud(fs), cloud(ft), candidates=5, candidate_rows=np.zeros(0, np.int64))
    sim = fs @ ft.T
    np.testing.assert_allclose(m.similarity, sim.max(axis=1), rtol=1e-6)
    flags = m.mutual(np.arange(5000))
    np.testing.assert_array_equal(flags, sim.argmax(axis=0)[sim.argmax(axis=1)] == np.arange(5000))
    assert 0 < flags.sum() <= 300
    unflagged = match_features(cloud(fs), cloud(ft), candidates=5, candidate_rows=np.zeros(0, np.int64),
                               mutual=False)
    assert unflagged.back is None  # the second search is skipped, the matches are the same
    np.testing.assert_array_equal(unflagged.target_index, m.target_index)


def test_against_an_inverted_file_the_mutual_check_searches_only_the_targets_asked_about():
    """A map's matches: the source's features are searched exactly for the targets a check asks
    about, and never the source's own index (a fused sequence's would be trained for nothing)."""
    rng = np.random.default_rng(4)
    fs, ft = unit_rows(rng, 3000), unit_rows(rng, 4000)
    source = SimpleNamespace(features=fs, index=FeatureIndex(fs, 1000, 16, 8))
    target = SimpleNamespace(features=ft, index=FeatureIndex(ft, 1000, 4000, 4000))  # probes every cell: exact
    m = match_features(source, target, candidates=5, candidate_rows=np.zeros(0, np.int64))
    sim = fs @ ft.T
    asked = np.arange(0, 3000, 7)
    np.testing.assert_array_equal(m.mutual(asked), sim.argmax(axis=0)[m.target_index[asked]] == asked)
    assert source.index._cells is None  # the source's inverted file was never trained
    everything = m.mutual(np.arange(3000))
    order = np.lexsort((-m.similarity, ~everything))
    for count in (10, 200, 2999, 3000):
        np.testing.assert_array_equal(m.mutual_first(count), np.sort(order[:count]))


def test_best_subset_takes_mutual_matches_first():
    from regor_ros.core.config import InitialConfig
    from regor_ros.core.initial import consensus_subset
    from regor_ros.core.matching import FeatureMatches
    n = 1000
    mutual = np.zeros(n, bool)
    mutual[::10] = True
    similarity = np.linspace(0, 1, n).astype(np.float32)
    matches = FeatureMatches(np.arange(n), similarity, lambda targets: np.where(mutual[targets], targets, -1),
                             np.arange(0), np.zeros((0, 1), int), np.zeros((0, 1)))
    best = consensus_subset(matches, InitialConfig(max_correspondences=300, subset="best"), None)
    assert set(np.flatnonzero(mutual)) <= set(best)
    assert similarity[np.setdiff1d(best, np.flatnonzero(mutual))].min() > 0.7
    rng = np.random.default_rng(0)
    random = consensus_subset(matches, InitialConfig(max_correspondences=300), rng)
    assert len(random) == 300 and len(np.unique(random)) == 300
    everything = consensus_subset(matches, InitialConfig(max_correspondences=0), rng)
    np.testing.assert_array_equal(everything, np.arange(n))
