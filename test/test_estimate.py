import numpy as np
import pytest
from conftest import random_motion
from scipy.spatial.transform import Rotation

from regor_ros.core.estimate import (
    PointRefinement,
    inliers_at,
    plane_refine,
    plane_thresholds,
    point_refine,
    point_refine_all,
    pose_covariance,
    post_refine,
    post_refine_all,
    settled,
    weighted_kabsch,
)
from regor_ros.core.geometry import attached_pose, to_matrix, transform_points
from regor_ros.core.metrics import rotation_error_deg, translation_error
from regor_ros.core.neighbour_grid import NeighbourGrid


def cauchy_weights(residual, threshold):
    """The refinements' robust weights, as the compiled moments form them: a residual at the
    threshold counts half, far ones fade without a cut-off."""
    return 1.0 / (1.0 + (residual / threshold) ** 2)


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


def test_post_refine_is_reweighted_kabsch_on_the_inliers_each_pose_on_its_own():
    """The compiled refinement of a batch of poses is, pose by pose, the definition: Kabsch on the
    current inliers, Cauchy-weighted, until their count stops changing (the sums run in another
    order: the last bits may differ)."""
    rng = np.random.default_rng(6)
    src = rng.uniform(-2, 2, size=(400, 3))
    T = random_motion(7)
    tgt = transform_points(T, src) + rng.normal(scale=0.01, size=(400, 3))
    tgt[:150] = rng.uniform(-5, 5, size=(150, 3))
    nudged = [T.copy() for _ in range(5)]
    for seed, pose in enumerate(nudged):
        pose[:3, 3] += np.random.default_rng(seed).uniform(-0.04, 0.04, 3)
    starts = np.stack(nudged + [random_motion(99)])

    def defined(pose, iterations):
        previous = 0
        for _ in range(iterations):
            residual = np.linalg.norm(transform_points(pose, src) - tgt, axis=1)
            inliers = residual < 0.1
            if inliers.sum() in (previous, 0, 1, 2):
                break
            previous = int(inliers.sum())
            pose = weighted_kabsch(src[inliers], tgt[inliers], cauchy_weights(residual[inliers], 0.1))
        return pose

    for iterations in (1, 20):
        refined = post_refine_all(starts, src, tgt, 0.1, iterations)
        np.testing.assert_allclose(refined, [defined(start, iterations) for start in starts], atol=1e-9)
    assert translation_error(refined[0], T) < 0.005


def test_point_refinement_converges_from_a_perturbed_pose(kitchen_pair):
    src, tgt, T_gt, _ = kitchen_pair
    from regor_ros.core import RegorConfig, prepare_cloud
    cfg = RegorConfig()
    s, t = prepare_cloud(src, cfg), prepare_cloud(tgt, cfg)
    start = random_motion(9, max_translation=0.05)
    start[:3, :3] = np.eye(3)
    start = start @ T_gt
    assert translation_error(start, T_gt) > 0.02
    result = point_refine(start, s.points, t.neighbours, threshold=0.1, iterations=20)
    assert translation_error(result.transform, T_gt) < 0.05
    assert rotation_error_deg(result.transform, T_gt) < 3.0
    assert len(result.source_index) > 0.5 * len(s)
    assert (result.distances < 0.1).all()


def _refinement(T, points, residual=0.0):
    return PointRefinement(T, np.arange(len(points)), np.arange(len(points)), np.full(len(points), residual))


def test_a_pose_is_refined_on_until_a_round_moves_it_less_than_it_is_known():
    points = np.random.default_rng(3).uniform(-10, 10, (200, 3))
    goal = to_matrix(np.eye(3), np.array([2.0, 0.0, 0.0]))
    rounds = []

    def halfway(T):   # a refinement that gets half way to the goal each round
        rounds.append(T)
        return _refinement(to_matrix(np.eye(3), (T[:3, 3] + goal[:3, 3]) / 2), points)

    start = _refinement(np.eye(4), points)
    out = settled(start, halfway, points, voxel_size=0.3, rounds=3)
    # 1 m, 0.5 m, 0.25 m: each round moved it more than a voxel's sigma (0.087 m), so it takes the last
    assert len(rounds) == 3 and np.allclose(out.transform[:3, 3], [1.75, 0.0, 0.0])
    rounds.clear()
    near = _refinement(to_matrix(np.eye(3), np.array([1.95, 0.0, 0.0])), points)
    assert settled(near, halfway, points, voxel_size=0.3, rounds=3) is near   # it has settled: returned as it was
    assert len(rounds) == 1
    worse = settled(start, lambda T: _refinement(goal, points, residual=1.0), points, voxel_size=0.3,
                    rounds=3)
    assert worse is start   # a round that fits the data worse at the keypoints' resolution is not taken


def test_plane_thresholds_halve_tau_e_down_to_the_voxel_size():
    assert plane_thresholds(1.2, 0.3) == [1.2, 0.6, 0.3]
    assert plane_thresholds(0.10, 0.05) == [0.10, 0.05]
    assert plane_thresholds(0.10, 0.30) == [0.10]


def _floor(offset):
    """A 10 m x 10 m floor of points (normals up) and a pose that lifts and slides it by ``offset``."""
    x, y = np.meshgrid(np.arange(0.0, 10.0, 0.1), np.arange(0.0, 10.0, 0.1))
    points = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    return points, normals, to_matrix(np.eye(3), np.array(offset))


def test_plane_refinement_fixes_what_the_surfaces_fix_and_leaves_the_rest():
    """A floor fixes height, roll and pitch, never a slide along it: the slide the point level
    left stays (damping), the height is corrected."""
    points, normals, start = _floor([0.3, -0.2, 0.05])
    T = plane_refine(start, points, NeighbourGrid(points), normals, [0.4, 0.2], 0.1)
    np.testing.assert_allclose(T[:3, 3], [0.3, -0.2, 0.0], atol=1e-3)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-6)


def test_plane_refinement_keeps_its_rotation_inside_the_clamp():
    points, normals, start = _floor([0.0, 0.0, 0.05])
    start[:3, :3] = Rotation.from_euler("x", 3.0, degrees=True).as_matrix()
    kept = start[:3, :3].copy()
    T = plane_refine(start, points, NeighbourGrid(points), normals, [0.4, 0.2], 0.1,
                     clamp=lambda R: np.broadcast_to(kept, R.shape))
    np.testing.assert_allclose(T[:3, :3], kept, atol=1e-12)
    assert abs(transform_points(T, points)[:, 2].mean()) < 0.01  # the height still fitted under it


class _CountedGrid(NeighbourGrid):
    """A NeighbourGrid that counts the searches a refinement asks of it (one per step)."""

    searches = 0

    def nearest_within(self, queries, threshold):
        self.searches += 1
        return super().nearest_within(queries, threshold)


def test_plane_refinement_stops_once_its_steps_are_below_the_resolution(kitchen_pair):
    """On a real pair a few millimetres off: at the indoor voxel the steps soon move the keypoints
    by less than a tenth of its sigma and a threshold ends there, in fewer steps than where the
    grid is a thousand times finer; the poses the two reach lie well within the coarser voxel's
    sigma of each other, and both on the truth."""
    from regor_ros.core import RegorConfig, prepare_cloud
    src, tgt, T_gt, _ = kitchen_pair
    voxel = RegorConfig().features.voxel_size
    s = prepare_cloud(src, RegorConfig())
    t = prepare_cloud(tgt, RegorConfig())
    turn = Rotation.from_euler("z", 0.5, degrees=True).as_matrix()
    start = to_matrix(turn, np.array([0.01, -0.01, 0.005])) @ T_gt
    coarse, fine = _CountedGrid(t.points), _CountedGrid(t.points)
    thresholds = plane_thresholds(0.1, voxel)
    at_voxel = plane_refine(start, s.points, coarse, t.normals, thresholds, voxel)
    finer = plane_refine(start, s.points, fine, t.normals, thresholds, voxel / 1000)
    assert coarse.searches < fine.searches
    sigma = voxel / np.sqrt(12.0)
    lever = np.sqrt(np.mean(np.sum((s.points - s.points.mean(axis=0)) ** 2, axis=1)))
    assert translation_error(at_voxel, finer) < sigma
    assert np.radians(rotation_error_deg(at_voxel, finer)) * lever < sigma
    for T in (at_voxel, finer):
        assert translation_error(T, T_gt) < 2 * voxel and rotation_error_deg(T, T_gt) < 1.0


AXES = np.array([1.0, 2.0, 3.0])


def ellipsoid(n, seed):
    """Points and unit normals on an ellipsoid with distinct axes: every motion changes it."""
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3))
    points = AXES * points / np.linalg.norm(points, axis=1, keepdims=True)
    normals = points / AXES ** 2
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def test_covariance_is_symmetric_positive_definite_and_shrinks_with_noise():
    src, normals = ellipsoid(500, 6)
    T = random_motion(7)
    tgt = transform_points(T, src)
    normals = normals @ T[:3, :3].T
    noise = np.random.default_rng(8).normal(size=(500, 3))
    loose = pose_covariance(T, src, tgt + 0.05 * noise, normals, 0.05)
    tight = pose_covariance(T, src, tgt + 0.005 * noise, normals, 0.05)
    assert np.allclose(loose, loose.T)
    assert np.all(np.linalg.eigvalsh(loose) > 0)
    assert np.all(np.diag(tight) < np.diag(loose))
    assert np.diag(loose).max() < 1.0


def test_covariance_of_a_plane_leaves_sliding_unconstrained():
    rng = np.random.default_rng(9)
    src = np.c_[rng.uniform(-1, 1, size=(400, 2)), np.zeros(400)]
    normals = np.tile([0.0, 0.0, 1.0], (400, 1))
    cov = pose_covariance(np.eye(4), src, src + rng.normal(scale=0.001, size=src.shape), normals, 0.05)
    assert cov[0, 0] >= 1e6 and cov[1, 1] >= 1e6 and cov[5, 5] >= 1e6   # x, y, yaw slide freely
    assert cov[2, 2] < 1.0 and cov[3, 3] < 1.0 and cov[4, 4] < 1.0      # z, roll, pitch are fixed


def test_covariance_does_not_depend_on_where_the_target_origin_is():
    """A scan 1 km from a map's origin is as well constrained as one at the origin (the lever arm
    once made the rotation-translation system singular there: the pose was withheld)."""
    src, normals = ellipsoid(500, 10)
    T = random_motion(11)
    tgt = transform_points(T, src) + np.random.default_rng(12).normal(scale=0.01, size=src.shape)
    normals = normals @ T[:3, :3].T
    near = pose_covariance(T, src, tgt, normals, 0.05)
    far_T = T.copy()
    far_T[:3, 3] += [1000.0, -800.0, 20.0]
    far = pose_covariance(far_T, src, tgt + far_T[:3, 3] - T[:3, 3], normals, 0.05)
    np.testing.assert_allclose(far, near, rtol=1e-4, atol=1e-12)
    assert np.linalg.eigvalsh(far).max() < 1.0


def test_covariance_is_never_finer_than_the_voxel_grid():
    """A perfect fit of thousands of keypoints still knows the position only to its voxels."""
    src, normals = ellipsoid(2000, 13)
    cov = pose_covariance(np.eye(4), src, src, normals, 0.3)
    assert np.all(np.diag(cov)[:3] >= 0.3 ** 2 / 12 * 0.999)
    assert np.all(np.diag(cov)[3:] > 0) and np.diag(cov).max() < 1.0


def test_covariance_grows_along_the_direction_the_surfaces_constrain_weakly():
    """A corridor along x: walls, floor and ceiling face y and z; only 8 points of an end wall pin
    x, 50 times fewer than face y. The position along the corridor is then known about sqrt(50)
    times less well than across it, while across it stays at the voxel grid's resolution."""
    rng = np.random.default_rng(14)
    u = rng.uniform(-1, 1, size=(200, 2))
    walls = [np.c_[5 * u[:, 0], np.full(200, side), u[:, 1]] for side in (-1.0, 1.0)]
    floors = [np.c_[5 * u[:, 0], u[:, 1], np.full(200, side)] for side in (-1.0, 1.0)]
    end = np.c_[np.full(8, 5.0), rng.uniform(-1, 1, size=(8, 2))]
    src = np.vstack([*walls, *floors, end])
    normals = np.vstack([np.tile([0.0, 1.0, 0.0], (400, 1)), np.tile([0.0, 0.0, 1.0], (400, 1)),
                         np.tile([1.0, 0.0, 0.0], (8, 1))])
    cov = pose_covariance(np.eye(4), src, src, normals, 0.05)
    grid = 0.05 ** 2 / 12
    assert cov[1, 1] == pytest.approx(grid, rel=0.05) and cov[2, 2] == pytest.approx(grid, rel=0.05)
    assert 30 < cov[0, 0] / grid < 70
    assert np.linalg.eigvalsh(cov).max() < 1.0


def test_attached_pose_moves_with_the_lever_arm():
    """The base 1 m behind the sensor: the sensor's yaw uncertainty becomes sideways uncertainty."""
    T = to_matrix(Rotation.from_euler("z", 90, degrees=True).as_matrix(), np.array([5.0, 2.0, 0.0]))
    sensor_to_base = to_matrix(np.eye(3), np.array([-1.0, 0.0, 0.0]))
    covariance = np.diag([0.01, 0.01, 0.01, 1e-4, 1e-4, 0.04])
    base, moved = attached_pose(T, covariance, sensor_to_base)
    np.testing.assert_allclose(base[:3, 3], [5.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(base[:3, :3], T[:3, :3])
    assert moved[0, 0] == pytest.approx(0.01 + 0.04)   # the base swings along x when the sensor yaws
    assert moved[1, 1] == pytest.approx(0.01) and moved[5, 5] == pytest.approx(0.04)
    assert moved[0, 5] == pytest.approx(0.04) and np.allclose(moved, moved.T)


def _numpy_point_refine(T, source, grid, threshold, iterations):
    """point_refine as numpy expressions: each step the nearest pairs within the threshold and
    weighted_kabsch on them, until the count settles (what the compiled step replaced)."""
    previous, current = -1, inliers_at(T, source, grid, threshold)
    for _ in range(iterations):
        if len(current.source_index) == previous or len(current.source_index) < 3:
            break
        previous = len(current.source_index)
        T = weighted_kabsch(source[current.source_index], grid.points[current.target_index],
                            cauchy_weights(current.distances, threshold))
        current = inliers_at(T, source, grid, threshold)
    return current


def test_point_refinements_stepped_together_are_each_the_numpy_refinement(kitchen_pair):
    """A batch of starts (a gate's rivals) refined together: each gives what it gives alone, and
    what the numpy formulation gives (the same pairs; the pose up to rounding)."""
    src, tgt, T_gt, _ = kitchen_pair
    from regor_ros.core import RegorConfig, prepare_cloud
    cfg = RegorConfig()
    s, t = prepare_cloud(src, cfg), prepare_cloud(tgt, cfg)
    rng = np.random.default_rng(7)
    nudges = [to_matrix(Rotation.from_rotvec(rng.normal(0, np.radians(4), 3)).as_matrix(), rng.normal(0, 0.08, 3))
              for _ in range(6)]
    starts = np.array([nudge @ T_gt for nudge in nudges] + [random_motion(99)])   # the last far off: few pairs
    together = point_refine_all(starts, s.points, t.neighbours, 0.1, 20)
    for start, refined in zip(starts, together, strict=True):
        alone = point_refine(start, s.points, t.neighbours, 0.1, 20)
        expected = _numpy_point_refine(start, s.points, t.neighbours, 0.1, 20)
        np.testing.assert_array_equal(refined.transform, alone.transform)
        np.testing.assert_array_equal(refined.source_index, expected.source_index)
        np.testing.assert_array_equal(refined.target_index, expected.target_index)
        np.testing.assert_allclose(refined.transform, expected.transform, atol=1e-9)
        np.testing.assert_allclose(refined.distances, expected.distances, atol=1e-9)
    assert len({len(r.source_index) for r in together}) > 2   # the starts did not all end alike
    assert point_refine_all(np.zeros((0, 4, 4)), s.points, t.neighbours, 0.1, 20) == []
