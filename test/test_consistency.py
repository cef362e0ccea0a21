import numpy as np
from conftest import dense_power_iteration, dense_soft, length_residual, random_motion, unpacked

from regor_ros.core import kernels
from regor_ros.core.consistency import (
    compatibility,
    leading_eigenvector,
    second_order_top_k,
    top_k_stable,
    top_second_order,
)
from regor_ros.core.geometry import transform_points


def clique_problem(seed=0, inliers=30, outliers=70):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-2, 2, size=(inliers + outliers, 3))
    tgt = transform_points(random_motion(seed), src)
    tgt[inliers:] = rng.uniform(-2, 2, size=(outliers, 3))
    return src, tgt


def test_region_agreement_is_the_dense_definition_over_valid_slots():
    src, tgt = clique_problem(inliers=40, outliers=80)
    regions_src, regions_tgt = src.reshape(4, 30, 3), tgt.reshape(4, 30, 3)
    valid = np.random.default_rng(2).random((4, 30)) < 0.8
    agree = (length_residual(regions_src, regions_tgt) < 0.05) & valid[:, :, None] & valid[:, None, :]
    counts = kernels.region_agreement(regions_src, regions_tgt, valid, 0.05)
    np.testing.assert_array_equal(counts, agree.sum(axis=2))
    assert counts[0][valid[0]].min() >= valid[0].sum() - 1  # region 0 is all inliers: they agree


def test_second_order_scores_put_the_inlier_clique_above_outliers():
    src, tgt = clique_problem()
    assert set(top_second_order(src, tgt, 0.1, 30)) == set(range(30))


def test_top_second_order_is_the_dense_definition():
    src, tgt = clique_problem(inliers=40, outliers=160)
    hard = (length_residual(src, tgt) < 0.5).astype(np.float32)
    scores = ((hard @ hard) * hard).sum(axis=1)
    np.testing.assert_array_equal(top_second_order(src, tgt, 0.5, 120), top_k_stable(scores, 120))


def test_triangle_scores_are_the_dense_row_sums_on_any_runs():
    src, tgt = clique_problem(inliers=50, outliers=250)  # 300 rows: the last word of each row is partial
    hard = (length_residual(src, tgt) < 0.4).astype(np.int64)
    expected = ((hard @ hard) * hard).sum(axis=1)
    for runs in (1, 2, 3, 7):
        np.testing.assert_array_equal(kernels.triangle_scores(src, tgt, 0.4, runs), expected)


def test_spectral_confidence_ranks_inliers_first():
    src, tgt = clique_problem(seed=3)
    v = leading_eigenvector(compatibility(src, tgt, 0.1), 10)
    assert set(np.argsort(-v)[:30]) == set(range(30))


def test_leading_eigenvector_is_the_dense_power_iteration():
    """Up to float32 rounding (the sums run in another order), stopped at the same step: a
    problem that settles early, and one that does not within the iterations."""
    for inliers, outliers, iterations in ((60, 540, 10), (300, 300, 40), (20, 580, 3)):
        src, tgt = clique_problem(seed=4, inliers=inliers, outliers=outliers)
        compatible = compatibility(src, tgt, 0.2)
        expected = dense_power_iteration(dense_soft(compatible), iterations)
        v = leading_eigenvector(compatible, iterations)
        assert v.dtype == np.float32
        np.testing.assert_allclose(v, expected, rtol=0, atol=1e-6)


def test_top_k_stable_matches_a_stable_descending_sort():
    rng = np.random.default_rng(1)
    small = rng.integers(0, 4, size=(40, 25)).astype(np.float32)        # float32 keys
    large = rng.integers(0, 3, size=(5, 300)) * 100_000.0                 # beyond float32: float64
    for scores in (small, large):
        np.testing.assert_array_equal(top_k_stable(scores, 6),
                                      np.argsort(-scores, axis=1, kind="stable")[:, :6])


def test_compatibility_and_second_order_are_the_dense_definitions():
    # thresholds from sparse to dense; 600 rows span ten 64-bit words per packed row
    src, tgt = clique_problem(inliers=20, outliers=580)
    r = length_residual(src, tgt).astype(np.float32)
    rows = np.arange(0, 600, 7)
    for d in (0.01, 0.3, 1.0):
        compatible = compatibility(src, tgt, d)
        np.testing.assert_array_equal(dense_soft(compatible), np.maximum(0.0, 1.0 - r ** 2 / d ** 2))
        hard = unpacked(compatible.hard, 600)
        np.testing.assert_array_equal(hard, r < d)
        for i in rows:  # the sparse rows hold exactly the hard-compatible columns, ascending
            np.testing.assert_array_equal(compatible.columns[compatible.starts[i]:compatible.starts[i + 1]],
                                          np.flatnonzero(r[i] < d))
        dense_tight = (r < d / 2).astype(np.float32)
        np.testing.assert_array_equal(unpacked(compatible.tight, 600), r < d / 2)
        sc2 = (dense_tight[rows] @ dense_tight) * hard[rows]
        for k in (5, 20):  # few compatible columns: the zero-valued ones follow in index order
            np.testing.assert_array_equal(second_order_top_k(compatible, rows, k), top_k_stable(sc2, k))


def test_compatibility_with_heights_drops_pairs_whose_heights_disagree():
    src, tgt = clique_problem(inliers=50, outliers=150)
    offsets = np.random.default_rng(5).normal(0, 0.2, len(src))
    distance = np.linalg.norm(src[:, None] - src[None], axis=2)
    agree = np.abs(offsets[:, None] - offsets[None]) <= 0.3 + 0.1 * distance
    compatible = compatibility(src, tgt, 0.3, (offsets, 0.1))
    plain = compatibility(src, tgt, 0.3)
    n = len(src)
    np.testing.assert_array_equal(unpacked(compatible.hard, n), unpacked(plain.hard, n) & agree)
    np.testing.assert_array_equal(dense_soft(compatible), np.where(agree, dense_soft(plain), 0.0))
    assert not unpacked(compatible.tight, n)[~agree].any()
