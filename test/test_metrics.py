import numpy as np
import pytest
from conftest import random_motion

from regor_ros.core.metrics import (
    PairStats,
    feature_match_recall,
    is_success,
    pair_stats,
    rotation_error_deg,
    translation_error,
)


def rot_z(deg):
    T = np.eye(4)
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def test_rotation_and_translation_errors():
    T = rot_z(10)
    T[:3, 3] = [0.3, 0.4, 0]
    assert rotation_error_deg(T, np.eye(4)) == pytest.approx(10)
    assert translation_error(T, np.eye(4)) == pytest.approx(0.5)
    assert rotation_error_deg(random_motion(1), random_motion(1)) == pytest.approx(0, abs=1e-5)


def test_success_thresholds_per_kind():
    T = rot_z(10)
    assert is_success(T, np.eye(4), "indoor")
    assert not is_success(T, np.eye(4), "outdoor")
    T = np.eye(4)
    T[0, 3] = 0.5
    assert not is_success(T, np.eye(4), "indoor") and is_success(T, np.eye(4), "outdoor")


def test_pair_stats_ratios():
    src = np.zeros((4, 3))
    tgt = np.array([[0, 0, 0], [0.05, 0, 0], [1, 0, 0], [2, 0, 0]])
    s = pair_stats(src[:2], tgt[:2], src, tgt, np.eye(4), 0.1)
    assert (s.inliers_final, s.final_count, s.inliers_initial, s.initial_count) == (2, 2, 2, 4)
    assert s.inlier_precision == 1.0 and s.inlier_number_ratio == 1.0
    assert s.initial_inlier_ratio == 0.5


def test_empty_final_set_and_zero_initial_inliers():
    s = PairStats(inliers_final=7, final_count=0, inliers_initial=0, initial_count=10)
    assert s.inlier_precision == 0.0
    assert s.inlier_number_ratio == 7.0


def test_feature_match_recall():
    stats = [PairStats(0, 0, 6, 100), PairStats(0, 0, 5, 100), PairStats(0, 0, 50, 100)]
    assert feature_match_recall(stats) == pytest.approx(2 / 3)
    assert feature_match_recall([]) == 0.0
