"""A robot's relocalization workflow with the installed node over DDS: big clouds from a reliable
driver under `ros2 run` defaults, the map from a file (cached), the base pose for Nav2, and the
relocalize service."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
from conftest import DATA, load_map_query, require_shared_data, samplings
from ros_helpers import TIMEOUT, NodeProcess
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from regor_ros.core.metrics import is_success, rotation_error_deg, translation_error
from regor_ros.ros.input_qos import fixed_profile
from regor_ros.ros.parameters import parse_pose
from regor_ros.ros.pointcloud import cloud_to_xyz, xyz_to_cloud
from regor_ros.ros.transport import PROFILE_VARIABLES
from regor_ros.tools.pair_client import pose_to_matrix

ANSWER_TIMEOUT = 30.0


def _driver_cloud_file(tmp_path: Path) -> Path:
    """130 k real OS1-64 points (five consecutive scans fused along odometry): 4.2 MB as a driver
    sends it (x y z intensity ring time)."""
    from regor_ros.bench.datasets import load_sequence
    _, _, queries = load_sequence(DATA / "maps" / "scaloam_mulran_kaist03")
    fused = next(q for q in queries if q.history is not None and len(q.history.scans) == 5).history.fused()
    path = tmp_path / "driver_cloud.npy"
    np.save(path, fused.points[:130_000])
    return path


def _answers(ros, driver, stamps) -> int:
    """Clouds answered (a status for their stamp) of those published one after another."""
    answered = 0
    for stamp in stamps:
        driver.stdin.write(f"{stamp}\n")
        driver.stdin.flush()
        answered += ros.spin_until(lambda: any(s.get("source_stamp") == stamp for s in ros.statuses),
                                   ANSWER_TIMEOUT)
    return answered


def _driver(cloud_file: Path, reliability: str, env) -> subprocess.Popen:
    driver = subprocess.Popen([sys.executable, str(Path(__file__).with_name("cloud_publisher.py")),
                               str(cloud_file), reliability], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=env)
    assert driver.stdout.readline().strip() == "ready"
    return driver


def test_big_clouds_from_a_reliable_driver_arrive_under_defaults(install, ros, tmp_path):
    """Neither the driver's process nor the environment the node starts in names a Fast DDS
    profile; the node subscribes with its defaults (auto QoS) and loads its own transports."""
    require_shared_data("the transport test")
    plain = {k: v for k, v in os.environ.items() if k not in PROFILE_VARIABLES}
    cloud_file = _driver_cloud_file(tmp_path)
    ros.publish(target=xyz_to_cloud(np.load(DATA / "maps" / "scaloam_mulran_kaist03" / "map.npy"),
                                    ros.header("map")))
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros" / "share" / "regor_ros" / "config" / "outdoor.yaml"),
                       "-p", "mode:=map", "-r", "__node:=register_node", env=plain)
    driver = _driver(cloud_file, "reliable", plain)
    try:
        assert ros.wait_for_node(TIMEOUT), node.output()
        assert _answers(ros, driver, range(1, 11)) == 10, node.output()
        status = ros.statuses[-1]
        assert status["source_qos"] == "auto: reliable" and status["target_qos"] == "auto: reliable, transient local"
        assert status["source_clouds"] == 10 and status["dropped_stale"] == 0, status
        assert "large-data transports" in node.output()
        driver.stdin.close()
        driver.wait(timeout=10)

        # a best-effort driver that loads the profile, as before: the subscription follows it
        driver = _driver(cloud_file, "best_effort", dict(os.environ))
        assert ros.spin_until(lambda: "subscribed best effort" in node.output(), 10.0), node.output()
        ros.spin_until(lambda: False, 1.0)  # the driver discovers the new subscription
        assert _answers(ros, driver, range(101, 104)) == 3, node.output()
        assert ros.statuses[-1]["source_qos"] == "auto: best effort"
    finally:
        if driver.poll() is None:
            driver.stdin.close()
            driver.wait(timeout=10)
        assert node.stop() < 5.0


BASE_TO_SENSOR = "0.4, -0.1, 1.2, 0.0, 0.05, 0.3"  # the sensor's mounting on the robot


def _relocalize(ros, scan=None, timeout=TIMEOUT):
    """Call relocalize; publish ``scan`` once the call is under way; the response."""
    client = ros.create_client(Trigger, "/register_node/relocalize")
    try:
        assert client.wait_for_service(timeout_sec=TIMEOUT)
        future = client.call_async(Trigger.Request())
        ros.spin_until(lambda: False, 1.0)  # the call reaches the node before the scan
        if scan is not None:
            ros.publish(source=xyz_to_cloud(scan, ros.header("livox")))
        assert ros.spin_until(future.done, timeout)
        return future.result()
    finally:
        ros.destroy_client(client)


def _listening(ros) -> bool:
    """The node subscribes to source_cloud (a node with a map file has no target_cloud)."""
    found = ros.spin_until(lambda: ros.source_pub.get_subscription_count() > 0, TIMEOUT)
    ros.spin_until(lambda: False, 1.0)
    return found


RELOCALIZE_TIMEOUT = 10.0  # how long a relocalize call waits for a scan: 4 s was missed with two suites running


def _start(install, map_file: Path, trajectory: Path):
    return NodeProcess(install, "--params-file",
                       str(install / "regor_ros" / "share" / "regor_ros" / "config" / "outdoor.yaml"),
                       "-p", "mode:=map", "-p", f"map_file:={map_file}", "-p", f"map_trajectory_file:={trajectory}",
                       "-p", "registration:=on_demand", "-p", f"relocalize_timeout:={RELOCALIZE_TIMEOUT}",
                       "-p", "base_frame:=base_link", "-p", f"base_to_sensor:='{BASE_TO_SENSOR}'",
                       "-r", "__node:=register_node")


def test_a_map_file_is_cached_and_the_base_pose_answers_relocalize(install, ros, tmp_path):
    """The real Avia map as a PCD file and its trajectory as TUM: the node prepares it, caches it
    in the cache folder, publishes it once on map_cloud; relocalize without a scan says so, with one
    it answers with the verdict and publishes the base pose. A restart loads the cache; a changed
    map file is prepared again."""
    scan, cloud, truth = load_map_query("fastlio_avia_hku2", "scan_000005")
    map_file, trajectory = tmp_path / "hku.pcd", tmp_path / "hku_trajectory.txt"
    o3d.io.write_point_cloud(str(map_file), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud)))
    trajectory.write_text((DATA / "maps" / "fastlio_avia_hku2" / "map_trajectory.txt").read_text())
    maps = []
    subscription = ros.create_subscription(PointCloud2, "map_cloud", maps.append,
                                           fixed_profile("transient_local"))
    expected_base = truth @ np.linalg.inv(parse_pose(BASE_TO_SENSOR, "base_to_sensor"))
    caches = []
    try:
        for start, cache in enumerate(("built", "loaded", "built")):
            if start == 2:  # the map file changes: its cache no longer matches
                o3d.io.write_point_cloud(str(map_file), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud[::2])))
            node = _start(install, map_file, trajectory)
            try:
                assert _listening(ros), node.output()
                if start == 0:
                    assert ros.spin_until(lambda: maps, TIMEOUT), node.output()
                    assert maps[-1].header.frame_id == "map" and 1000 < len(cloud_to_xyz(maps[-1])) < len(cloud)
                    empty = _relocalize(ros)
                    assert not empty.success and "no source cloud arrived" in empty.message
                seen = len(ros.poses)
                answer = _relocalize(ros, scan)
                assert answer.success, (answer.message, node.output())
                assert ros.spin_until(lambda: len(ros.poses) > seen, 10.0)
                T = pose_to_matrix(ros.poses[-1])
                assert is_success(T, expected_base, "outdoor"), (rotation_error_deg(T, expected_base),
                                                                 translation_error(T, expected_base))
                assert ros.spin_until(lambda: ros.statuses and ros.statuses[-1]["map_cache"] == cache, 10.0), \
                    (ros.statuses[-1:], node.output())
                status = ros.statuses[-1]
                assert status["pose_of"] == "base_link" and status["target_frame"] == "map"
                assert status["map_cache_file"].endswith(".regor-cache.npz") and \
                    not list(map_file.parent.glob("*.regor-cache.npz"))   # in the cache folder, not the map's
                caches.append(status["map_cache_file"])
            finally:
                assert node.stop() < 5.0
        # the changed map is another key: a cache of its own, the first one's left as it was
        assert caches[0] == caches[1] != caches[2] and Path(caches[0]).is_file()
    finally:
        ros.destroy_subscription(subscription)


def test_pose_with_covariance_is_the_base_pose_with_the_lever_arm(install, ros, tmp_path):
    """The covariance published is the sensor's carried to the base: never below the voxel grid's
    resolution, and turning the sensor also moves the base (the lever arm couples them)."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    scan, cloud, _ = load_map_query("fastlio_avia_hku2", "scan_000005")
    map_file = tmp_path / "hku.npy"
    np.save(map_file, cloud)
    received = []
    subscription = ros.create_subscription(PoseWithCovarianceStamped, "pose_with_covariance", received.append, 10)
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros" / "share" / "regor_ros" / "config" / "outdoor.yaml"),
                       "-p", "mode:=map", "-p", f"map_file:={map_file}", "-p", "map_cache:=false",
                       "-p", "base_frame:=base_link", "-p", f"base_to_sensor:='{BASE_TO_SENSOR}'",
                       "-r", "__node:=register_node")
    try:
        assert _listening(ros), node.output()
        ros.publish(source=xyz_to_cloud(scan, ros.header("livox")))
        assert ros.spin_until(lambda: received, TIMEOUT), node.output()
        covariance = np.array(received[-1].pose.covariance).reshape(6, 6)
        assert np.allclose(covariance, covariance.T) and np.all(np.linalg.eigvalsh(covariance) > 0)
        assert np.all(np.diag(covariance)[:3] >= 0.3 ** 2 / 12 * 0.999)   # outdoor voxel 0.3 m
        assert np.abs(covariance[:3, 3:]).max() > 1e-6   # the lever arm couples turn and position
        assert ros.statuses[-1]["map_cache"] == "off"
    finally:
        ros.destroy_subscription(subscription)
        assert node.stop() < 5.0


def _imu_message(ros, orientation_xyzw=None, acceleration=(0.0, 0.0, 9.81)):
    from sensor_msgs.msg import Imu
    msg = Imu(header=ros.header("imu"))
    if orientation_xyzw is None:
        msg.orientation_covariance[0] = -1.0   # REP 145: no orientation reported
    else:
        msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = orientation_xyzw
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = acceleration
    return msg


def test_the_source_up_comes_from_an_imu_and_a_tipped_over_sensor_gets_no_pose(install, ros):
    """Ground-vehicle scans (MulRan, OS1-64 on a car, 12 m apart) with the gravity prior: the
    source's up from an IMU that reports accelerations only (level: a pose), then from one whose
    orientation says the sensor lies on its side (the true pose is 90 deg outside the cone: none)."""
    from scipy.spatial.transform import Rotation
    from sensor_msgs.msg import Imu
    require_shared_data("the IMU test")
    pair = DATA / "pairs_hard" / "mulran_riv02_048_to_044"
    src, tgt, T_gt = np.load(pair / "src.npy"), np.load(pair / "tgt.npy"), np.loadtxt(pair / "gt.txt")
    imu = ros.create_publisher(Imu, "imu", 50)
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros" / "share" / "regor_ros" / "config" / "outdoor.yaml"),
                       "-p", "imu_topic:=imu", "-p", "imu_window:=5.0", "-p", "gravity.target_up:='0 0 1'",
                       "-p", "gravity.height_tolerance:=0.5", "-p", "max_stamp_difference:=1.0",
                       "-r", "__node:=register_node")  # a map latched by an earlier test is too old to pair
    try:
        assert ros.wait_for_node(TIMEOUT), node.output()
        assert ros.spin_until(lambda: imu.get_subscription_count() > 0, TIMEOUT)
        for _ in range(10):
            imu.publish(_imu_message(ros, acceleration=(0.05, -0.03, 9.81)))
        ros.spin_until(lambda: False, 0.5)
        pose, status = ros.register_pair(src, tgt, TIMEOUT)
        assert status is not None, node.output()
        assert status["source_up"]["from"].startswith("mean IMU acceleration"), status["source_up"]
        up = np.array(status["source_up"]["direction"].split(), dtype=float)
        assert np.degrees(np.arccos(up[2])) < 0.5 and status["target_up"] == "0 0 1"
        assert pose is not None, status["reason"]
        T = pose_to_matrix(pose)
        assert is_success(T, T_gt, "outdoor"), (rotation_error_deg(T, T_gt), translation_error(T, T_gt))

        on_its_side = Rotation.from_euler("x", 90, degrees=True).as_quat()
        for _ in range(3):
            imu.publish(_imu_message(ros, orientation_xyzw=on_its_side))
        ros.spin_until(lambda: False, 0.5)
        pose, status = ros.register_pair(src, tgt, TIMEOUT)
        assert status is not None, node.output()
        assert status["source_up"]["from"] == "IMU orientation"
        up = np.array(status["source_up"]["direction"].split(), dtype=float)
        assert abs(up[1]) > 0.99, up
        assert pose is None and not status["accepted"], status
    finally:
        ros.destroy_publisher(imu)
        assert node.stop() < 5.0


def test_a_robot_switched_on_at_rest_without_odometry_starts_from_its_scans_fused(install, ros):
    """No odometry, the sensor at rest: the node says it is gathering, waits for accumulate_scans
    scans (published at 10 Hz, stamped as a driver stamps them), finds from the scans that the
    sensor did not move, and its first registration is of the three fused: a pose."""
    from conftest import REPO

    from regor_ros.ros.messages import stamp_seconds
    demo = REPO / "demo"
    scan, truth = np.load(demo / "src.npy"), np.loadtxt(demo / "gt.txt")
    frames = samplings(scan, 3)   # a resting sensor's frames
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros" / "share" / "regor_ros" / "config" / "indoor.yaml"),
                       "-p", "mode:=map", "-p", f"map_file:={demo / 'tgt.npy'}", "-p", "map_cache:=false",
                       "-p", "accumulate_scans:=3", "-p", "rest_wait:=60.0", "-r", "__node:=register_node")
    try:
        assert _listening(ros), node.output()
        seen = len(ros.statuses)
        stamps = []
        for frame in frames:
            message = xyz_to_cloud(frame, ros.header("camera"))
            stamps.append(stamp_seconds(message.header))
            ros.source_pub.publish(message)
            ros.spin_until(lambda: False, 0.1)
        assert ros.spin_until(lambda: any(s.get("source_stamp") == stamps[-1] for s in ros.statuses[seen:]),
                              ANSWER_TIMEOUT), node.output()
        first = ros.statuses[seen]
        assert first["source_stamp"] == stamps[-1], "registered before the scans at rest were gathered"
        assert first["accumulation"]["scans_fused"] == 3 and first["accumulation"]["at_rest"], first
        assert first["accepted"], first["reason"]
        assert ros.spin_until(lambda: any(p.header.stamp == message.header.stamp for p in ros.poses), 10.0)
        pose = next(p for p in ros.poses if p.header.stamp == message.header.stamp)
        T = pose_to_matrix(pose)
        assert is_success(T, truth, "indoor"), (rotation_error_deg(T, truth), translation_error(T, truth))
    finally:
        assert node.stop() < 5.0
    assert "gathering up to 3 scans" in node.output()
