import numpy as np
import pytest
from conftest import random_motion

from regor_ros.core.metrics import correct_mask, is_success, rotation_error_deg, translation_error


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


def test_correct_matches_are_those_the_truth_brings_together():
    src = np.zeros((4, 3))
    tgt = np.array([[0, 0, 0], [0.05, 0, 0], [1, 0, 0], [2, 0, 0]])
    assert correct_mask(src, tgt, np.eye(4), 0.1).tolist() == [True, True, False, False]
