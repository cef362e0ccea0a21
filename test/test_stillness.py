"""Whether the sensor stayed still between two scans (core/stillness.py), from the scans alone: two
samplings of one real scan are still, the same scan moved by a voxel or turned by a degree is not,
nor a plane (rest cannot be told from sliding along it); at_rest fuses the run of still scans at
identity and stops at the first that moved. On the bundled real scan; on the shared Avia, OS1 and
ETH sequences, consecutive scans of a robot in motion are never said still."""
import numpy as np
import pytest
from conftest import DATA, REPO, require_shared_data, samplings
from scipy.spatial.transform import Rotation

from regor_ros.core import RegorConfig, ScanSequence, at_rest, to_matrix, transform_points, was_still

SCAN = np.load(REPO / "demo" / "src.npy")        # 3DMatch redkitchen, an RGB-D fragment: indoor
INDOOR = RegorConfig.preset("indoor").features
VOXEL, RADIUS = INDOOR.voxel_size, INDOOR.normal_radius


def test_two_samplings_of_one_scan_are_still():
    older, newer = samplings(SCAN, 2)
    verdict = was_still(older, newer, VOXEL, RADIUS)
    assert verdict.still and verdict.reason == "", verdict
    assert verdict.moved_m < 0.5 * VOXEL and verdict.overlap > 0.8 and verdict.constrained


@pytest.mark.parametrize("motion", ["a voxel's shift", "a degree's turn"])
def test_the_same_scan_moved_is_not_still(motion):
    older, newer = samplings(SCAN, 2)
    T = (to_matrix(np.eye(3), [VOXEL, 0.0, 0.0]) if motion == "a voxel's shift"
         else to_matrix(Rotation.from_euler("y", 1.0, degrees=True).as_matrix(), np.zeros(3)))
    verdict = was_still(older, transform_points(T, newer), VOXEL, RADIUS)
    assert not verdict.still and "moved" in verdict.reason, verdict


def test_a_plane_cannot_be_told_from_sliding_along_it():
    rng = np.random.default_rng(1)
    plane = np.column_stack([rng.uniform(-2, 2, (2, 4000)).T, np.full(4000, 1.5)])
    verdict = was_still(plane[:2000], plane[2000:], VOXEL, RADIUS)
    assert not verdict.still and not verdict.constrained and "free" in verdict.reason, verdict


def test_at_rest_fuses_the_run_of_still_scans_and_stops_at_one_that_moved():
    moved_away = transform_points(to_matrix(np.eye(3), [0.5, 0.0, 0.0]), samplings(SCAN, 4, seed=2)[0])
    scans = [moved_away, *samplings(SCAN, 3)]            # oldest first: the sensor came to rest after it
    sequence, why = at_rest(scans, VOXEL, RADIUS)
    assert isinstance(sequence, ScanSequence) and len(sequence.scans) == 3
    assert all(np.array_equal(pose, np.eye(4)) for pose in sequence.poses)
    assert sequence.scans[-1] is scans[-1] and "moved" in why
    alone, why = at_rest([moved_away, scans[-1]], VOXEL, RADIUS)
    assert alone is None and why


def test_consecutive_scans_of_a_robot_in_motion_are_never_said_still():
    """Every pair of consecutive scans the shared sequences hold (a hand-held Avia, a car's OS1-64,
    a park's scanner, each step a robot in motion, some short but turned). Fused at identity, any
    of them would smear the source."""
    require_shared_data("the moving sequences")
    from regor_ros.bench.datasets import consecutive_scans, load_sequence
    features = RegorConfig.preset("outdoor").features
    said_still = []
    for folder in ("maps/fastlio_avia_hku2", "maps/scaloam_mulran_kaist03", "revisit/avia_hku2_loop",
                   "xseason/eth_gazebo_summer_winter"):
        for a, b, _ in consecutive_scans(load_sequence(DATA / folder)[2]):
            verdict = was_still(a, b, features.voxel_size, features.normal_radius)
            if verdict.still:
                said_still.append((folder, verdict))
    assert not said_still, said_still
