import numpy as np
from scipy.spatial import cKDTree

from regor_ros.core.estimate import (pose_covariance, point_refine, post_refine, transform_points,
                                     weighted_kabsch)
from regor_ros.core.metrics import rotation_error_deg, translation_error

from conftest import random_motion


def test_kabsch_recovers_a_known_motion():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(50, 3))
    T = random_motion(1)
    np.testing.assert_allclose(weighted_kabsch(src, transform_points(T, src)), T, atol=1e-9)


def test_kabsch_is_batched_and_never_returns_a_reflection():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(4, 20, 3))
    Ts = np.stack([random_motion(s) for s in range(4)])
    tgt = np.einsum("bij,bnj->bni", Ts[:, :3, :3], src) + Ts[:, None, :3, 3]
    np.testing.assert_allclose(weighted_kabsch(src, tgt), Ts, atol=1e-9)
    mirrored = weighted_kabsch(src[0], src[0] * np.array([1, 1, -1]))
    assert np.linalg.det(mirrored[:3, :3]) > 0


def test_zero_weights_ignore_outliers():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(40, 3))
    T = random_motion(3)
    tgt = transform_points(T, src)
    tgt[:10] += rng.normal(scale=5.0, size=(10, 3))
    w = np.r_[np.zeros(10), np.ones(30)]
    np.testing.assert_allclose(weighted_kabsch(src, tgt, w), T, atol=1e-6)


def test_post_refine_recovers_pose_despite_outliers():
    rng = np.random.default_rng(4)
    src = rng.uniform(-2, 2, size=(300, 3))
    T = random_motion(5)
    tgt = transform_points(T, src) + rng.normal(scale=0.005, size=(300, 3))
    tgt[:100] = rng.uniform(-5, 5, size=(100, 3))
    start = T.copy()
    start[:3, 3] += 0.03
    refined = post_refine(start, src, tgt, threshold=0.1, iterations=20)
    assert translation_error(refined, T) < 0.005
    assert rotation_error_deg(refined, T) < 0.5


def test_point_refinement_converges_from_a_perturbed_pose(kitchen_pair):
    src, tgt, T_gt, _ = kitchen_pair
    from regor_ros.core import RegorConfig, prepare_cloud
    cfg = RegorConfig()
    s, t = prepare_cloud(src, cfg), prepare_cloud(tgt, cfg)
    start = random_motion(9, max_translation=0.05)
    start[:3, :3] = np.eye(3)
    start = start @ T_gt
    assert translation_error(start, T_gt) > 0.02
    result = point_refine(start, s.points, t.tree, threshold=0.1, iterations=20)
    assert translation_error(result.transform, T_gt) < 0.05
    assert rotation_error_deg(result.transform, T_gt) < 3.0
    assert len(result.source_index) > 0.5 * len(s)
    assert (result.distances < 0.1).all()


def test_covariance_is_symmetric_positive_definite_and_shrinks_with_noise():
    rng = np.random.default_rng(6)
    src = rng.uniform(-3, 3, size=(500, 3))
    T = random_motion(7)
    noise = rng.normal(size=(500, 3))
    loose = pose_covariance(T, src, transform_points(T, src) + 0.05 * noise)
    tight = pose_covariance(T, src, transform_points(T, src) + 0.005 * noise)
    assert np.allclose(loose, loose.T)
    assert np.all(np.linalg.eigvalsh(loose) > 0)
    assert np.all(np.diag(tight) < np.diag(loose))


def test_covariance_of_a_line_is_flagged_unconstrained():
    src = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    assert pose_covariance(np.eye(4), src, src)[3, 3] >= 1e6
