"""The watchdog: a localization stack's pose checked against the scans, without ROS and over DDS
with the installed node (a correct stack raises no alarm; a kidnapped robot is found again)."""
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import DATA, require_shared_data
from geometry_msgs.msg import PoseWithCovarianceStamped
from ros_helpers import TIMEOUT, NodeProcess
from std_msgs.msg import Header

from regor_ros.core import to_matrix
from regor_ros.core.metrics import is_success, rotation_error_deg, translation_error
from regor_ros.ros.messages import pose_from_matrix
from regor_ros.ros.pointcloud import xyz_to_cloud
from regor_ros.ros.watchdog import LOST, SUSPECT, VERIFIED, TrackedPose, Watchdog
from regor_ros.tools.pair_client import pose_to_matrix

XSEASON = DATA / "xseason" / "eth_gazebo_summer_winter"
LOST_AFTER = 2
CHECK_TIMEOUT = 60.0


class Verified:
    """What Watchdog.judged reads of a verify() result."""

    def __init__(self, accepted):
        self.accepted, self.reason = accepted, "" if accepted else "surfaces pass through each other"
        self.correction_m, self.correction_deg = 0.1, 0.5

    def summary(self):
        accepted = self.accepted
        return SimpleNamespace(as_json=lambda: {"accepted": accepted})


def test_a_pose_that_cannot_be_checked_says_why():
    watchdog = Watchdog()
    assert "no pose" in watchdog.pose_for(10.0, "map", 0.5)[1]
    watchdog.track(TrackedPose(9.0, "map", np.eye(4)))
    assert "1.00 s from its stamp" in watchdog.pose_for(10.0, "map", 0.5)[1]
    watchdog.track(TrackedPose(10.1, "odom", np.eye(4)))
    assert "in 'odom'" in watchdog.pose_for(10.0, "map", 0.5)[1]
    watchdog.track(TrackedPose(10.05, "map", np.full((4, 4), np.nan)))
    assert "not finite" in watchdog.pose_for(10.0, "map", 0.5)[1]
    watchdog.track(TrackedPose(10.0, "map", np.eye(4)))
    pose, why = watchdog.pose_for(10.0, "map", 0.5)
    assert pose is not None and not why
    check = watchdog.unchecked("the tracked pose is not finite", 10.0)
    assert check.state == "unchecked" and check.failures == 0


def test_failures_in_a_row_make_the_robot_lost_and_a_verified_check_clears_them():
    watchdog = Watchdog()
    states = [watchdog.judged(Verified(ok), 1.0, 1.0, 3).state for ok in (False, False, False, True, False)]
    assert states == [SUSPECT, SUSPECT, LOST, VERIFIED, SUSPECT]
    watchdog.found()
    assert watchdog.failures == 0
    check = watchdog.judged(Verified(True), 2.0, 2.0, 3)
    assert check.as_dict()["correction_m"] == 0.1   # a verified pose's correction is reported
    assert check.as_dict()["verification"] == {"accepted": True}   # with verify()'s summary


@pytest.fixture
def watched(install, ros, tmp_path):
    """The installed node with the summer map, on-demand registration, the watchdog at 2 Hz; a
    publisher of the stack's pose; the winter queries."""
    require_shared_data("the watchdog over DDS")
    from regor_ros.bench.datasets import load_sequence
    _, _, queries = load_sequence(XSEASON)
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros" / "share" / "regor_ros" / "config" / "outdoor.yaml"),
                       "-p", "mode:=map", "-p", f"map_file:={XSEASON / 'map.npy'}",
                       "-p", f"map_trajectory_file:={XSEASON / 'map_trajectory.txt'}", "-p", "map_cache:=false",
                       "-p", "registration:=on_demand", "-p", "accumulate_scans:=1", "-p", "verify_rate:=2.0",
                       "-p", f"lost_after:={LOST_AFTER}", "-r", "__node:=register_node")
    tracked = ros.create_publisher(PoseWithCovarianceStamped, "tracked_pose", 10)
    try:
        assert ros.spin_until(lambda: ros.source_pub.get_subscription_count() > 0
                              and tracked.get_subscription_count() > 0, TIMEOUT), node.output()
        ros.spin_until(lambda: False, 1.0)
        yield node, tracked, queries
    finally:
        ros.destroy_publisher(tracked)
        assert node.stop() < 5.0


def _check(ros, tracked, scan, pose, stamp: int) -> dict:
    """Publish the stack's pose and the scan at ``stamp``; the watchdog's check of that scan."""
    header = Header(frame_id="map")
    header.stamp.sec = stamp
    message = PoseWithCovarianceStamped(header=header)
    message.pose.pose = pose_from_matrix(pose)
    tracked.publish(message)
    ros.spin_until(lambda: False, 0.2)
    scan_header = Header(frame_id="laser")
    scan_header.stamp.sec = stamp
    ros.publish(source=xyz_to_cloud(scan, scan_header))
    ros.spin_until(lambda: any(s.get("scan_stamp") == stamp for s in ros.statuses), CHECK_TIMEOUT)
    return next((s for s in ros.statuses if s.get("scan_stamp") == stamp), {})


def test_a_correct_stack_raises_no_alarm_and_a_kidnapped_robot_is_found(watched, ros):
    node, tracked, queries = watched
    stamps = iter(range(1000, 2000))
    for query in queries[:5]:
        check = _check(ros, tracked, query.scan, query.truth, next(stamps))
        assert check.get("watchdog") == VERIFIED, (check, node.output())
        assert check["correction_m"] < 0.6   # reported, not raised
    # kidnapped: the stack goes on, 10 m off, then turned by 90 degrees
    turn = to_matrix(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3))
    for offset, wrong in (("10 m", lambda T: to_matrix(np.eye(3), np.array([10.0, 0.0, 0.0])) @ T),
                          ("90 deg", lambda T: T @ turn)):
        seen = len(ros.poses)
        states = []
        for query in queries[5:5 + LOST_AFTER]:
            states.append(_check(ros, tracked, query.scan, wrong(query.truth), next(stamps)).get("watchdog"))
        assert states == [SUSPECT] * (LOST_AFTER - 1) + [LOST], (offset, states, node.output())
        # relocalized on the scan that found it lost: the pose goes out
        assert ros.spin_until(lambda: len(ros.poses) > seen, CHECK_TIMEOUT), (offset, node.output())
        truth = queries[5 + LOST_AFTER - 1].truth
        T = pose_to_matrix(ros.poses[-1])
        assert is_success(T, truth, "outdoor"), (offset, rotation_error_deg(T, truth), translation_error(T, truth))
