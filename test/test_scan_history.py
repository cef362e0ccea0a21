"""Which scans are fused with the newest one, and where odometry puts each."""
import numpy as np
from scipy.spatial.transform import Rotation

from regor_ros.core.geometry import to_matrix
from regor_ros.core.scan_history import AccumulationLimits, ScanHistory


def pose(x, yaw_deg=0.0):
    return to_matrix(Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix(), np.array([x, 0.0, 0.0]))


def scan(i):
    return np.full((10, 3), float(i))


def test_odometry_is_interpolated_between_the_messages_around_a_scan():
    history = ScanHistory(10)
    history.add_odometry(2.0, pose(2.0, 20.0))
    history.add_odometry(1.0, pose(1.0, 10.0))   # out of order
    between = history.pose_at(1.5, tolerance=0.6)
    np.testing.assert_allclose(between, pose(1.5, 15.0), atol=1e-9)
    assert history.pose_at(1.5, tolerance=0.2) is None         # a gap too wide to interpolate over
    np.testing.assert_allclose(history.pose_at(2.1, tolerance=0.2), pose(2.0, 20.0))   # nearest within
    assert history.pose_at(2.5, tolerance=0.2) is None


def test_the_newest_scans_with_odometry_within_the_limits_are_fused_oldest_first():
    history = ScanHistory(20)
    for i in range(8):
        history.add_scan(float(i), scan(i))
        if i != 5:                                   # scan 5 has no odometry
            history.add_odometry(float(i), pose(2.0 * i))
    sequence, info = history.sequence(7.0, AccumulationLimits(scans=4, max_distance=100, max_age=100, tolerance=0.01))
    assert [s[0, 0] for s in sequence.scans] == [3.0, 4.0, 6.0, 7.0]
    np.testing.assert_allclose(sequence.poses[-1], pose(14.0))
    assert info == {"scans_fused": 4, "without_odometry": 1, "span_m": 8.0, "more_to_fuse": 0}
    near, _ = history.sequence(7.0, AccumulationLimits(scans=4, max_distance=5.0, max_age=100, tolerance=0.01))
    assert [s[0, 0] for s in near.scans] == [6.0, 7.0]
    recent, _ = history.sequence(7.0, AccumulationLimits(scans=4, max_distance=100, max_age=1.5, tolerance=0.01))
    assert [s[0, 0] for s in recent.scans] == [6.0, 7.0]


def test_without_odometry_for_the_newest_scan_it_is_registered_alone():
    history = ScanHistory(5)
    history.add_scan(1.0, scan(1))
    history.add_scan(2.0, scan(2))
    history.add_odometry(1.0, pose(0.0))
    sequence, info = history.sequence(2.0, AccumulationLimits(scans=5, tolerance=0.1))
    assert sequence is None and info["without_odometry"] == 1 and "registered alone" in info["reason"]
    assert info["more_to_fuse"] == 0   # without odometry no scan is fused, however many arrive


def test_a_scan_fused_with_fewer_than_wanted_says_how_many_more_will_be():
    history = ScanHistory(10)
    limits = AccumulationLimits(scans=5, max_distance=100, max_age=100, tolerance=0.01)
    history.add_scan(1.0, scan(1))
    history.add_odometry(1.0, pose(0.0))
    alone, info = history.sequence(1.0, limits)
    assert alone is None and info["scans_fused"] == 1 and info["more_to_fuse"] == 4
    history.add_scan(2.0, scan(2))
    history.add_odometry(2.0, pose(1.0))
    fused, info = history.sequence(2.0, limits)
    assert len(fused.scans) == 2 and info["more_to_fuse"] == 3


def test_the_number_of_scans_kept_follows_the_capacity_given_and_keeps_the_newest():
    history = ScanHistory(2)
    for i in range(3):
        history.add_scan(float(i), scan(i))
    assert [s for s, _ in history.scans] == [1.0, 2.0]
    history.add_scan(3.0, scan(3), capacity=4)
    history.add_scan(4.0, scan(4), capacity=4)
    assert [s for s, _ in history.scans] == [1.0, 2.0, 3.0, 4.0]
    history.add_scan(5.0, scan(5), capacity=2)
    assert [s for s, _ in history.scans] == [4.0, 5.0]
