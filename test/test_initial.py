import numpy as np
from conftest import random_motion

from regor_ros.core import RegorConfig, prepare_cloud
from regor_ros.core.geometry import transform_points
from regor_ros.core.initial import SUPPORT_ROWS, candidate_support, initial_stage
from regor_ros.core.matching import match_features
from regor_ros.core.metrics import is_success


def test_candidate_support_counts_keypoints_landing_on_a_candidate():
    rng = np.random.default_rng(4)
    rows, k = 300, 8
    source = rng.uniform(-5, 5, size=(rows, 3))
    T = random_motion(2)
    candidates = rng.uniform(-5, 5, size=(rows, k, 3))
    has_true = rng.random(rows) < 0.4
    slot = rng.integers(0, k, rows)
    truth = transform_points(T, source) + rng.normal(0, 0.01, size=(rows, 3))
    candidates[has_true, slot[has_true]] = truth[has_true]
    planes = np.ascontiguousarray(np.moveaxis(candidates, 2, 0), dtype=np.float32)

    support = candidate_support(np.stack([T, np.eye(4)]), source, planes, 0.1)
    sampled = np.unique(np.linspace(0, rows - 1, SUPPORT_ROWS).astype(int))
    assert support[0] == has_true[sampled].sum()
    assert support[1] < 5


def test_both_rankings_find_the_kitchen_pose(kitchen_pair):
    src, tgt, T_gt, kind = kitchen_pair
    for ranking in ("inliers", "candidates"):
        cfg = RegorConfig().replace({"ranking": ranking})
        source, target = prepare_cloud(src, cfg), prepare_cloud(tgt, cfg)
        rows = np.arange(len(source))
        matches = match_features(source, target, cfg.initial.candidates, rows)
        result = initial_stage(source.points, target.points[matches.target_index], source, target,
                               matches, cfg.initial, np.random.default_rng(0))
        assert is_success(result.transform, T_gt, kind), ranking
