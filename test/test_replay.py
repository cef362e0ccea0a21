"""regor-replay on rosbag2 recordings written here from a shared sequence (the rosbags library):
MCAP and sqlite3, with and without odometry, and the inputs it refuses in one line."""
import csv

import numpy as np
import pytest
from conftest import DATA, require_shared_data
from scipy.spatial.transform import Rotation

from regor_ros.tools.replay import main

SEQUENCE = DATA / "xseason" / "eth_gazebo_summer_winter"
SCANS = 5   # the first winter scans, one a second


def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def _header(store, seconds: float, frame: str):
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    return Header(stamp=Time(sec=int(seconds), nanosec=int(round((seconds % 1) * 1e9))), frame_id=frame)


def _cloud(store, points: np.ndarray, seconds: float, fields="xyz"):
    PointCloud2, PointField = store.types["sensor_msgs/msg/PointCloud2"], store.types["sensor_msgs/msg/PointField"]
    data = np.ascontiguousarray(points, dtype="<f4")
    layout = [PointField(name=name, offset=4 * i, datatype=7, count=1) for i, name in enumerate(fields)]
    return PointCloud2(header=_header(store, seconds, "laser"), height=1, width=len(data), fields=layout,
                       is_bigendian=False, point_step=12, row_step=12 * len(data),
                       data=data.view(np.uint8).reshape(-1), is_dense=True)


def _pose(store, T: np.ndarray):
    Pose, Point, Quaternion = (store.types[f"geometry_msgs/msg/{n}"] for n in ("Pose", "Point", "Quaternion"))
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return Pose(position=Point(x=T[0, 3], y=T[1, 3], z=T[2, 3]), orientation=Quaternion(x=x, y=y, z=z, w=w))


def write_bag(path, storage: str, odometry: bool = True, fields: str = "xyz", tracked=None):
    """The first SCANS winter scans on /points, their odometry on /odom and their true poses in
    the summer map on /truth, as a robot's recording would hold them; with ``tracked`` (a function
    of the true pose and the scan's number) a localization stack's pose on /amcl_pose."""
    require_shared_data("the replay tests")
    from rosbags.rosbag2 import StoragePlugin, Writer

    from regor_ros.tools.map_benchmark import load_poses
    store = _typestore()
    poses = load_poses(SEQUENCE / "odometry.txt")
    Odometry = store.types["nav_msgs/msg/Odometry"]
    PoseStamped = store.types["geometry_msgs/msg/PoseStamped"]
    PoseWithCovariance = store.types["geometry_msgs/msg/PoseWithCovariance"]
    TwistWithCovariance, Twist, Vector3 = (store.types[f"geometry_msgs/msg/{n}"]
                                           for n in ("TwistWithCovariance", "Twist", "Vector3"))
    still = TwistWithCovariance(twist=Twist(linear=Vector3(x=0, y=0, z=0), angular=Vector3(x=0, y=0, z=0)),
                                covariance=np.zeros(36))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        topics = {"/points": writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=store),
                  "/truth": writer.add_connection("/truth", "geometry_msgs/msg/PoseStamped", typestore=store)}
        if odometry:
            topics["/odom"] = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        if tracked:
            topics["/amcl_pose"] = writer.add_connection("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped",
                                                         typestore=store)
        for k in range(SCANS):
            folder = SEQUENCE / "queries" / f"scan_{k:06d}"
            seconds = 100.0 + k
            truth = np.loadtxt(folder / "gt.txt")
            messages = [("/truth", PoseStamped(header=_header(store, seconds, "map"), pose=_pose(store, truth)))]
            if tracked:
                Stamped = store.types["geometry_msgs/msg/PoseWithCovarianceStamped"]
                messages.append(("/amcl_pose", Stamped(header=_header(store, seconds, "map"), pose=PoseWithCovariance(
                    pose=_pose(store, tracked(truth, k)), covariance=np.zeros(36)))))
            if odometry:
                messages.append(("/odom", Odometry(header=_header(store, seconds, "odom"), child_frame_id="laser",
                                                   pose=PoseWithCovariance(pose=_pose(store, poses[k]),
                                                                           covariance=np.zeros(36)),
                                                   twist=still)))
            messages.append(("/points", _cloud(store, np.load(folder / "scan.npy"), seconds, fields)))
            for topic, message in messages:
                writer.write(topics[topic], int(seconds * 1e9), store.serialize_cdr(message, message.__msgtype__))
    return path


def replay(bag, out, *extra):
    return main([str(bag), "--map", str(SEQUENCE / "map.npy"), "--map-trajectory",
                 str(SEQUENCE / "map_trajectory.txt"), "--scan-topic", "/points", "--set", "map_cache=false",
                 "--out", str(out), *map(str, extra)])


def test_an_mcap_recording_is_replayed_with_odometry_and_scored_against_its_reference(tmp_path, capsys):
    bag = write_bag(tmp_path / "winter", "mcap")
    assert replay(bag, tmp_path / "out", "--odom-topic", "/odom", "--reference-topic", "/truth") == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "registrations.csv")))
    assert [float(r["stamp"]) for r in rows] == [100.0 + k for k in range(SCANS)]
    assert all(r["accepted"] == "True" and r["agrees"] == "True" for r in rows), rows
    assert all(float(r["reference_translation_error_m"]) < 0.6 for r in rows)
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert f"{SCANS} of {SCANS} published poses agree" in summary and "no odometry" not in summary
    assert (tmp_path / "out" / "map.png").stat().st_size > 10_000
    assert summary in capsys.readouterr().out
    assert not (SEQUENCE / "map.npy.regor-cache.npz").exists()   # --set map_cache=false is a boolean false


def test_a_sqlite3_recording_without_odometry_every_two_seconds(tmp_path):
    bag = write_bag(tmp_path / "winter", "sqlite3", odometry=False)
    assert replay(bag, tmp_path / "out", "--every", 2, "--reference-topic", "/truth") == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "registrations.csv")))
    assert [float(r["stamp"]) for r in rows] == [100.0, 102.0, 104.0]
    assert "no odometry: every scan was registered alone" in (tmp_path / "out" / "summary.md").read_text()


@pytest.mark.parametrize("case, says", [
    ("missing topic", "--scan-topic '/velodyne_points' is not in the bag (its topics: /odom, /points, /truth)"),
    ("no xyz", "cannot be read: no z field"),
    ("truncated", "cannot be read as a rosbag2"),
    ("no bag", "winter: no such file or folder"),
])
def test_what_cannot_be_replayed_is_said_in_one_line(tmp_path, capsys, case, says):
    bag = tmp_path / "winter"
    if case == "no xyz":
        write_bag(bag, "mcap", fields="xyw")
    elif case != "no bag":
        write_bag(bag, "mcap")
    if case == "truncated":
        recording = next(bag.glob("*.mcap"))
        recording.write_bytes(recording.read_bytes()[:2000])
    topic = ["--scan-topic", "/velodyne_points"] if case == "missing topic" else []
    assert replay(bag, tmp_path / "out", *topic) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "\n" not in err and "Traceback" not in err


def test_the_watchdog_on_a_recording_says_when_the_stack_is_lost_and_relocalizes(tmp_path):
    """The stack's pose is right for two scans, then 10 m off: suspect, then lost (lost_after=2),
    and the scan that finds it lost is registered (the relocalization)."""
    def stack(truth, k):
        return truth if k < 2 else np.vstack([truth[:3] + [[0, 0, 0, 10.0], [0] * 4, [0] * 4], truth[3:]])
    bag = write_bag(tmp_path / "winter", "mcap", tracked=stack)
    assert replay(bag, tmp_path / "out", "--odom-topic", "/odom", "--tracked-topic", "/amcl_pose",
                  "--every", 1000, "--set", "lost_after=2") == 0
    checks = list(csv.DictReader(open(tmp_path / "out" / "watchdog.csv")))
    assert [c["watchdog"] for c in checks] == ["verified", "verified", "suspect", "lost", "suspect"], checks
    rows = list(csv.DictReader(open(tmp_path / "out" / "registrations.csv")))
    assert [float(r["stamp"]) for r in rows] == [100.0, 103.0]   # the first scan, and the relocalization
    assert all(r["accepted"] == "True" for r in rows)
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "5 checks of the stack's pose: 2 verified, 2 suspect, 1 lost" in summary
