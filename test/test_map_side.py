"""The map's side of the free-space check, scans fused along odometry, and the safe viewpoint
defaults, on the real scan-to-map sequences."""
import numpy as np
import pytest
from conftest import DATA, require_shared_data
from scipy.spatial.transform import Rotation

from regor_ros.bench.datasets import load_sequence
from regor_ros.core import RegistrationError, RegorConfig, ScanSequence, prepare_cloud, register
from regor_ros.core.gate.visibility import visibility_figures
from regor_ros.core.geometry import to_matrix
from regor_ros.core.metrics import ERROR_SIGMAS_99, error_sigmas, is_success

OUTDOOR = RegorConfig.preset("outdoor")
SEQUENCE = "fastlio_avia_hku2"


@pytest.fixture(scope="module")
def avia():
    """The Livox Avia map (no viewpoint), its trajectory and queries by id."""
    require_shared_data("the map-side tests")
    cloud, trajectory, queries = load_sequence(DATA / "maps" / SEQUENCE)
    return cloud, trajectory, {q.id: q for q in queries}


def turned_about_z(T, degrees):
    return T @ to_matrix(Rotation.from_euler("z", degrees, degrees=True).as_matrix(), np.zeros(3))


def test_the_map_seen_from_the_pose_rejects_a_turned_scan(avia):
    """scan_000171 turned by 90 deg about its sensor: the map's surfaces seen from there stand
    behind where the scan puts its own. (The scan's own side sees it too now that the map keeps
    its ground's keypoints; without them its free space was nearly empty of map points.)"""
    cloud, _, queries = avia
    query = queries["scan_000171"]
    gate = OUTDOOR.acceptance
    without_trajectory = prepare_cloud(cloud, OUTDOOR, "map")
    scan = prepare_cloud(query.scan, OUTDOOR, "scan", viewpoint=(0, 0, 0))
    right = visibility_figures(query.truth, scan, without_trajectory, gate)
    assert right.free_space_source is not None and right.map_seen > 0.9
    assert right.free_space_target <= gate.max_free_space_violation
    wrong = visibility_figures(turned_about_z(query.truth, 90), scan, without_trajectory, gate)
    assert wrong.free_space_target > 0.1                              # the map's side sees it


def test_a_scan_the_partial_threshold_withheld_is_published_once_the_map_side_is_checked(avia):
    cloud, trajectory, queries = avia
    query = queries["scan_000039"]   # fewer agreeing matches than min_feature_inliers_partial
    result = register(query.scan, prepare_cloud(cloud, OUTDOOR, "map", trajectory=trajectory), OUTDOOR)
    assert is_success(result.transform, query.truth, "outdoor")
    assert result.feature_inliers < OUTDOOR.acceptance.min_feature_inliers_partial
    assert result.accepted and result.figures.both_sides, result.reason
    assert result.summary().visibility.map_seen > 0.9


def test_the_covariance_covers_the_error_along_narrow_scans_weak_directions(avia):
    """The Livox Avia's scans (5 k points in a narrow field), refined point to point: every pose
    published is right and lies within its covariance's 99 % ellipsoid. Some are off by more than
    the sigma of their best-fixed axis, in the directions their surfaces constrain least, and
    within it along that axis: the covariance is shaped by the surfaces, not one radius. (Refined
    point to plane they are closer still.)"""
    cloud, trajectory, queries = avia
    point_level = OUTDOOR.replace({"estimation.plane_refinement": False})
    target = prepare_cloud(cloud, point_level, "map", trajectory=trajectory)
    published = shaped = 0
    for query in queries.values():
        result = register(query.scan, target, point_level)
        if not result.accepted:
            continue
        published += 1
        assert is_success(result.transform, query.truth, "outdoor"), query.id
        assert error_sigmas(result.transform, query.truth, result.covariance) < ERROR_SIGMAS_99, query.id
        variances, axes = np.linalg.eigh(result.covariance[:3, :3])
        error = axes.T @ (result.transform[:3, 3] - query.truth[:3, 3])
        shaped += abs(error[0]) < np.sqrt(variances[0]) < np.linalg.norm(error)
    assert published >= len(queries) // 2 and shaped >= 1


def test_scans_fused_along_odometry_find_a_scan_that_alone_is_lost():
    # the loop's way back (revisit/): scan 200 looks the other way from the map's nearest pose
    require_shared_data("the revisit sequence")
    cloud, trajectory, queries = load_sequence(DATA / "revisit" / "avia_hku2_loop")
    query = next(q for q in queries if q.id == "scan_000200")
    target = prepare_cloud(cloud, OUTDOOR, "map", trajectory=trajectory)
    alone = register(query.scan, target, OUTDOOR)
    assert not is_success(alone.transform, query.truth, "outdoor") and not alone.accepted
    fused = register(query.history, target, OUTDOOR)
    assert len(query.history.scans) == 5
    assert is_success(fused.transform, query.truth, "outdoor") and fused.accepted, fused.reason
    # the pose is the newest scan's, and the source side sees through every scan
    prepared = prepare_cloud(query.history, OUTDOOR, "fused")
    assert len(prepared.views) == 5
    np.testing.assert_allclose(prepared.viewpoints[-1], 0.0, atol=1e-9)


def test_a_fused_sequence_is_the_scans_moved_by_odometry_into_the_newest_frame():
    rng = np.random.default_rng(3)
    scans = [rng.uniform(-5, 5, (200, 3)) for _ in range(3)]
    poses = [to_matrix(Rotation.from_euler("z", 10 * i, degrees=True).as_matrix(), np.array([i, 0.0, 0.0]))
             for i in range(3)]
    fused = ScanSequence(scans, poses).fused()
    newest_from_first = np.linalg.inv(poses[2]) @ poses[0]
    np.testing.assert_allclose(fused.parts[0], scans[0] @ newest_from_first[:3, :3].T + newest_from_first[:3, 3])
    np.testing.assert_allclose(fused.parts[2], scans[2])
    np.testing.assert_allclose(fused.viewpoints[0], newest_from_first[:3, 3])
    with pytest.raises(RegistrationError, match="2 scans but 1 odometry"):
        ScanSequence(scans[:2], poses[:1])
    with pytest.raises(RegistrationError, match="odometry pose 1: not a rigid"):
        ScanSequence(scans[:2], [poses[0], 2 * poses[1]]).fused()
    with pytest.raises(RegistrationError, match="scan 0"):
        ScanSequence([np.zeros((5, 2)), scans[1]], poses[:2]).fused()


def test_a_map_gets_no_viewpoint_by_default_and_a_contradicting_one_raises(kitchen_pair):
    src, tgt, _, _ = kitchen_pair
    as_map = prepare_cloud(tgt, RegorConfig())
    assert as_map.viewpoints is None and as_map.map_view is not None
    seen = prepare_cloud(tgt, RegorConfig(), viewpoint=(0, 0, 0))
    assert len(seen.views) == 1 and seen.map_view is None
    register(src, as_map, RegorConfig(), target_viewpoint=None)           # agrees: fine
    register(src, seen, RegorConfig(), target_viewpoint=(0.0, 0.0, 0.0))  # agrees: fine
    with pytest.raises(RegistrationError, match="contradicts the viewpoint the target was prepared with"):
        register(src, as_map, RegorConfig(), target_viewpoint=(0, 0, 0))
    with pytest.raises(RegistrationError, match="contradicts"):
        register(src, seen, RegorConfig(), target_viewpoint=(1.0, 0.0, 0.0))
    with pytest.raises(RegistrationError, match="trajectory"):
        prepare_cloud(tgt, RegorConfig(), trajectory=np.zeros((4, 2)))
