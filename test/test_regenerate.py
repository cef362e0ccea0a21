import numpy as np
from conftest import random_motion
from scipy.spatial import cKDTree

from regor_ros.core.cloud import PreparedCloud
from regor_ros.core.config import FeatureConfig, RegenerationConfig
from regor_ros.core.feature_index import FeatureIndex
from regor_ros.core.geometry import transform_points, unique_rows
from regor_ros.core.regenerate import LocalMatches, global_filter, three_point_filter


def cloud(points):
    features = np.zeros((len(points), 33), np.float32)
    return PreparedCloud(points, np.zeros_like(points), features, cKDTree(points),
                         FeatureIndex(features, 100, 1, 1), FeatureConfig(), len(points))


def region_problem():
    """Two regions of 8 matches each around seeds 0 and 8; region 1 has 6 corrupted matches."""
    rng = np.random.default_rng(0)
    src = rng.uniform(-1, 1, size=(16, 3))
    T = random_motion(1)
    tgt = transform_points(T, src)
    tgt[10:] = rng.uniform(-3, 3, size=(6, 3))
    index = np.arange(16).reshape(2, 8)
    m = LocalMatches(index, index, np.ones((2, 8), bool), np.array([8, 8]))
    seeds_src, seeds_tgt = src[[0, 8]], transform_points(T, src[[0, 8]])
    return cloud(src), cloud(tgt), m, seeds_src, seeds_tgt


def test_ctc_keeps_a_consistent_region_and_drops_a_corrupted_one():
    src, tgt, m, seed_src, seed_tgt = region_problem()
    keep = three_point_filter(seed_src, seed_tgt, m, src, tgt, RegenerationConfig(), 16)
    assert keep[0].all()
    assert not keep[1].any()


def test_ctc_keeps_every_region_rather_than_none():
    src, tgt, m, seed_src, seed_tgt = region_problem()
    m = LocalMatches(m.source_index[1:], m.target_index[1:], m.valid[1:], m.count[1:])
    keep = three_point_filter(seed_src[1:], seed_tgt[1:], m, src, tgt, RegenerationConfig(), 16)
    np.testing.assert_array_equal(keep[0], np.r_[np.ones(2, bool), np.zeros(6, bool)])


def test_ctc_ignores_padded_slots_unless_reproducing_the_authors_bug():
    src, tgt, m, seed_src, seed_tgt = region_problem()
    # region 1 padded to 40 slots; keypoint 0 is consistent with seed 8, so the bug counts 32 extra
    cfg = RegenerationConfig()
    fixed = three_point_filter(seed_src, seed_tgt, m, src, tgt, cfg, 40)
    buggy = three_point_filter(seed_src, seed_tgt, m, src, tgt,
                               RegenerationConfig(reproduce_ctc_padding_bug=True), 40)
    assert not fixed[1].any()
    assert buggy[1, :2].all()


def test_global_filter_keeps_the_consistent_majority():
    rng = np.random.default_rng(3)
    src = rng.uniform(-2, 2, size=(200, 3))
    tgt = transform_points(random_motion(2), src)
    tgt[150:] = rng.uniform(-2, 2, size=(50, 3))
    chosen = global_filter(src, tgt, RegenerationConfig(), rng)
    assert len(chosen) == 40
    assert (chosen < 150).all()


def test_unique_rows_gives_numpys_unique_rows_and_first_occurrences():
    """Matches merged by regeneration and cells of the evidence: negative coordinates, spans too
    wide to pack (numpy's own row sort then), and no rows at all."""
    rng = np.random.default_rng(3)
    cases = [rng.integers(0, 40, (3000, 2)), rng.integers(-30, 30, (4000, 3)),
             rng.integers(-2 ** 40, 2 ** 40, (50, 3)), np.zeros((0, 2), np.int64)]
    for values in cases:
        rows, first = unique_rows(values)
        expected_rows, expected_first = np.unique(values, axis=0, return_index=True)
        np.testing.assert_array_equal(rows, expected_rows)
        np.testing.assert_array_equal(first, expected_first)


def test_column_bounds_are_the_columns_minimum_and_maximum():
    """Bit for bit what min(axis=0) and max(axis=0) give, integers and floats (NaN included)."""
    from regor_ros.core.geometry import column_bounds
    rng = np.random.default_rng(4)
    floats = rng.normal(size=(500, 3))
    floats[7, 1] = np.nan
    for values in (rng.integers(-2 ** 40, 2 ** 40, (1000, 3)), floats, rng.random((1, 4)).astype(np.float32)):
        low, high = column_bounds(values)
        np.testing.assert_array_equal(low, values.min(axis=0))
        np.testing.assert_array_equal(high, values.max(axis=0))
        assert low.dtype == values.dtype
