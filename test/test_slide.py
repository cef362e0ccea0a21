"""The surfaces' support along the direction they pin least (gate/slide.py), and the gate's verdict
on a pose slid along a bookshelf."""
import dataclasses

import numpy as np
import pytest
from conftest import EARLIER_INDOOR, load_threedmatch

from regor_ros.core import ORIGIN, RegorConfig, judge, prepare_cloud, register
from regor_ros.core.gate.slide import weakest_support
from regor_ros.core.metrics import rotation_error_deg, translation_error

RADIUS = 0.25


def plane(normal, offset, extent=2.0, step=0.05):
    """Points of a square patch with the given normal, ``offset`` along it."""
    normal = np.asarray(normal, dtype=float)
    u = np.cross(normal, [0.0, 0.0, 1.0] if abs(normal[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    a, b = np.meshgrid(np.arange(0, extent, step), np.arange(0, extent, step))
    points = a.reshape(-1, 1) * u + b.reshape(-1, 1) * v + offset * normal
    return points, np.tile(normal, (len(points), 1))


def support(*planes):
    points = np.vstack([p for p, _ in planes])
    normals = np.vstack([n for _, n in planes])
    return weakest_support(np.eye(4), (points, points, normals), 0.05, RADIUS)


def test_surfaces_facing_every_way_but_one_leave_that_way_unpinned():
    # a bookshelf's fronts and boards: nothing faces y, the way it slides
    value, direction = support(plane([1, 0, 0], 0.0), plane([0, 0, 1], 0.0), plane([0, 0, 1], 0.4))
    assert value < 1e-6
    assert abs(direction[1]) == pytest.approx(1.0)


def test_a_corner_is_pinned_by_many_neighbourhoods_each_way():
    value, _ = support(plane([1, 0, 0], 0.0), plane([0, 1, 0], 0.0), plane([0, 0, 1], 0.0))
    assert value > 10   # each wall is some thirty neighbourhoods of the descriptor radius


def test_support_counts_neighbourhoods_not_points():
    # a narrow strip facing y: the same neighbourhoods at a quarter of the spacing weigh the same
    coarse = support(plane([1, 0, 0], 0.0), plane([0, 0, 1], 0.0), plane([0, 1, 0], 0.0, extent=0.3))[0]
    fine = support(plane([1, 0, 0], 0.0, step=0.0125), plane([0, 0, 1], 0.0, step=0.0125),
                   plane([0, 1, 0], 0.0, extent=0.3, step=0.0125))[0]
    assert 0.2 < coarse < 5 and fine == pytest.approx(coarse, rel=0.5)


def test_nothing_on_the_surfaces_is_no_support():
    points, normals = plane([0, 0, 1], 0.0)
    value, _ = weakest_support(np.eye(4), (points + [0, 0, 0.5], points, normals), 0.05, RADIUS)
    assert value == 0.0


def register_fragments(scene, source, target, normals_toward_sensors=True):
    src, tgt, T_gt = load_threedmatch(scene, source, target)
    config = RegorConfig.preset("indoor").replace({**EARLIER_INDOOR,
                                                   "features.normals_toward_sensors": normals_toward_sensors})
    source, target = (prepare_cloud(cloud, config, viewpoint=ORIGIN) for cloud in (src, tgt))
    result = register(source, target, config)
    return result, T_gt


def test_a_pose_slid_along_a_bookshelf_is_withheld_as_ambiguous():
    # 3DMatch studyroom 45 -> 40 with the normals facing the sensors: the search's pose is 0.85 m
    # off along the shelves, free space not violated, 150 matches agreeing
    result, T_gt = register_fragments("studyroom", 45, 40)
    assert translation_error(result.transform, T_gt) > 0.5 and rotation_error_deg(result.transform, T_gt) < 5
    assert not result.accepted and result.reason.startswith("ambiguous"), result.reason
    # the search's next place, refined as the pose is, slides along the same shelves and sees
    # through them (free space over the bound): no rival counts, and the slide check withholds
    # the pose on its own, whatever the rivals say
    assert result.verdict.failed == "min_weakest_support", result.reason
    assert result.figures.weakest_support < 1
    without_rivals = dataclasses.replace(RegorConfig.preset("indoor").replace(EARLIER_INDOOR).acceptance,
                                         max_ambiguity=1.0)
    assert judge(result.figures, without_rivals).failed == "min_weakest_support"


def test_as_shipped_the_slid_pose_is_withheld_with_the_truth_as_the_next_candidate():
    # the same pair with the solver's normal signs (the indoor preset as shipped): slid 0.8 m, and
    # the search's next place is the truth (5.5 deg, 0.14 m: right by the benchmark's measure).
    # Refined as the pose is, that rival slides along the shelves toward it (no other answer), so
    # the slide check is what withholds the pose; the truth stays the next candidate
    result, T_gt = register_fragments("studyroom", 45, 40, normals_toward_sensors=False)
    assert translation_error(result.transform, T_gt) > 0.5
    assert not result.accepted and result.verdict.failed == "min_weakest_support", result.reason
    runner_up = result.candidates[1].transform
    assert translation_error(runner_up, T_gt) < 0.3 and rotation_error_deg(runner_up, T_gt) < 15


def test_a_right_pose_in_the_same_room_is_pinned_and_published():
    result, T_gt = register_fragments("studyroom", 41, 40)
    assert translation_error(result.transform, T_gt) < 0.1
    assert result.accepted, result.reason
    assert result.figures.weakest_support > 1
