"""verify(): a pose found elsewhere, judged by the gate after a local refinement; regor-verify."""
import numpy as np
import pytest
from conftest import DATA, DEMO_PAIR, load_pair, require_shared_data

from regor_ros.core import RegistrationError, RegorConfig, is_success, prepare_cloud, to_matrix, verify
from regor_ros.tools.verify_cli import main as verify_main

INDOOR, OUTDOOR = RegorConfig.preset("indoor"), RegorConfig.preset("outdoor")


def moved(T, metres=0.0, degrees=0.0, axis=(0.0, 0.0, 1.0)):
    """``T`` turned by ``degrees`` about ``axis`` through the source's origin, then shifted along x."""
    from scipy.spatial.transform import Rotation
    R = Rotation.from_rotvec(np.radians(degrees) * np.asarray(axis)).as_matrix()
    return to_matrix(R, T[:3, 3] - R @ T[:3, 3] + np.array([metres, 0.0, 0.0])) @ T


@pytest.fixture(scope="module")
def demo():
    source, target, truth, _ = load_pair(DEMO_PAIR)
    return source, target, truth


def test_the_true_pose_and_one_nudged_are_verified(demo):
    source, target, truth = demo
    for given in (truth, moved(truth, 0.05, 1.0)):
        result = verify(source, target, given, INDOOR)
        assert result.accepted, result.reason
        assert is_success(result.transform, truth, "indoor")
        assert result.correction_m < INDOOR.verification.max_correction


def test_a_pose_the_data_move_beyond_the_tolerance_is_not_verified(demo):
    source, target, truth = demo
    result = verify(source, target, moved(truth, 0.2), INDOOR.replace({"verification.max_correction": 0.1}))
    assert not result.accepted and not result.within_tolerance
    assert "from where it was given" in result.reason
    assert result.correction_m > 0.1   # the correction is reported: where the data put the pose


def test_the_correction_must_leave_room_for_the_refined_poses_own_uncertainty(demo):
    """At the tolerance's edge the refined pose's error decides which side the truth is on: the
    correction must be within the tolerance by the pose's uncertainty at the keypoints' resolution
    (a voxel's standard deviation)."""
    source, target, truth = demo
    given = moved(truth, 0.2)
    wide = verify(source, target, given, INDOOR.replace({"verification.max_correction": 1.0}))
    assert wide.accepted, wide.reason
    sigma = INDOOR.features.voxel_size / np.sqrt(12.0)
    for room, verified in ((0.5, False), (1.5, True)):
        edge = INDOOR.replace({"verification.max_correction": wide.correction_m + room * sigma})
        result = verify(source, target, given, edge)
        assert result.accepted is verified and result.within_tolerance is verified, result.reason
        assert np.isclose(result.correction_m, wide.correction_m)
    assert "known to" in verify(source, target, given, INDOOR.replace(
        {"verification.max_correction": wide.correction_m + 0.5 * sigma})).reason


def test_a_turned_room_is_not_verified(demo):
    source, target, truth = demo
    for degrees in (90.0, 180.0):
        result = verify(source, target, moved(truth, degrees=degrees, axis=(0.0, 1.0, 0.0)), INDOOR)
        assert not result.accepted and result.reason


def test_bad_poses_are_refused_with_a_reason(demo):
    source, target, truth = demo
    for bad, words in ((np.full((4, 4), np.nan), "finite"), (np.eye(3), "4x4"), (2 * truth, "rigid")):
        with pytest.raises(RegistrationError, match=words):
            verify(source, target, bad, INDOOR)


@pytest.fixture(scope="module")
def summer_map():
    require_shared_data("the cross-season map")
    from regor_ros.bench.datasets import load_sequence
    cloud, trajectory, queries = load_sequence(DATA / "xseason" / "eth_gazebo_summer_winter")
    return prepare_cloud(cloud, OUTDOOR, "map", trajectory=trajectory), {q.id: q for q in queries}


@pytest.mark.parametrize("query_id", ["scan_000003", "scan_000024"])
def test_winter_scans_in_the_summer_map(summer_map, query_id):
    """Right poses are verified in a changed world, single and fused; wrong ones are not."""
    prepared, queries = summer_map
    query = queries[query_id]
    for source in (query.scan, query.history):
        for given in (query.truth, moved(query.truth, 0.2, 1.0)):
            result = verify(source, prepared, given, OUTDOOR)
            assert result.accepted, result.reason
        for wrong in (moved(query.truth, 2.0), moved(query.truth, degrees=90.0), moved(query.truth, degrees=180.0)):
            assert not verify(source, prepared, wrong, OUTDOOR).accepted


def test_regor_verify_exit_status_and_one_line(demo, tmp_path, capsys):
    source, target, truth = demo
    np.save(tmp_path / "src.npy", source)
    np.save(tmp_path / "tgt.npy", target)
    np.savetxt(tmp_path / "right.txt", truth)
    np.savetxt(tmp_path / "turned.txt", moved(truth, degrees=180.0, axis=(0.0, 1.0, 0.0)))
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    clouds = [str(tmp_path / "src.npy"), str(tmp_path / "tgt.npy")]
    assert verify_main([*clouds, str(tmp_path / "right.txt")]) == 0
    assert capsys.readouterr().out.startswith("verified")
    assert verify_main([*clouds, str(tmp_path / "turned.txt")]) == 1
    out = capsys.readouterr().out
    assert out.startswith("NOT verified: ") and out.count("\n") == 1
    assert verify_main([*clouds, str(tmp_path / "bad.txt")]) == 2
    err = capsys.readouterr().err
    assert "expected 16 numbers" in err and err.count("\n") == 1
