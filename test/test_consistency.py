import numpy as np
from conftest import random_motion
from scipy import sparse

from regor_ros.core.consistency import (
    compatibility,
    leading_eigenvector,
    length_residual,
    second_order,
    second_order_scores,
    top_k_stable,
)
from regor_ros.core.geometry import transform_points


def clique_problem(seed=0, inliers=30, outliers=70):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-2, 2, size=(inliers + outliers, 3))
    tgt = transform_points(random_motion(seed), src)
    tgt[inliers:] = rng.uniform(-2, 2, size=(outliers, 3))
    return src, tgt


def test_length_residual_is_zero_for_a_rigid_motion_and_batched():
    src, tgt = clique_problem(outliers=0)
    assert length_residual(src, tgt).max() < 1e-9
    batch = length_residual(np.stack([src, src]), np.stack([tgt, tgt]))
    assert batch.shape == (2, 30, 30) and batch.max() < 1e-9


def test_second_order_scores_put_the_inlier_clique_above_outliers():
    src, tgt = clique_problem()
    hard = (length_residual(src, tgt) < 0.1).astype(np.float32)
    scores = second_order_scores(hard)
    assert scores[:30].min() > scores[30:].max()


def test_spectral_confidence_ranks_inliers_first():
    src, tgt = clique_problem(seed=3)
    residual = length_residual(src, tgt)
    v = leading_eigenvector(np.maximum(0, 1 - residual ** 2 / 0.1 ** 2), 10)
    assert set(np.argsort(-v)[:30]) == set(range(30))


def test_top_k_stable_matches_a_stable_descending_sort():
    rng = np.random.default_rng(1)
    small = rng.integers(0, 4, size=(40, 25)).astype(np.float32)        # float32 keys
    large = rng.integers(0, 3, size=(5, 300)) * 100_000.0                 # beyond float32: float64
    for scores in (small, large):
        np.testing.assert_array_equal(top_k_stable(scores, 6),
                                      np.argsort(-scores, axis=1, kind="stable")[:, :6])


def test_compatibility_by_blocks_and_its_sparse_second_order_match_the_dense_definition():
    # 600 rows span three residual blocks; a tight threshold leaves the tight matrix sparse
    src, tgt = clique_problem(inliers=20, outliers=580)
    r = length_residual(src, tgt, np.float32)
    for d in (0.01, 1.0):  # sparse, then dense
        soft, hard, tight = compatibility(src, tgt, d)
        np.testing.assert_array_equal(soft, np.maximum(0.0, 1.0 - r ** 2 / d ** 2))
        np.testing.assert_array_equal(hard, (r < d).astype(np.float32))
        dense_tight = (r < d / 2).astype(np.float32)
        assert sparse.issparse(tight) == (d == 0.01)
        rows = np.arange(0, 600, 7)
        np.testing.assert_array_equal(second_order(tight, hard, rows),
                                      (dense_tight[rows] @ dense_tight) * hard[rows])
