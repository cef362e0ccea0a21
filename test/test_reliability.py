"""register_node under hostile input, load and faults: it never dies, never queues work, never
publishes a wrong pose with confidence, and stops cleanly. Real DDS on loopback, no mocks."""
import time

import numpy as np
from conftest import load_pair, moved_pair
from ros_helpers import TIMEOUT, NodeProcess, set_param
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from regor_ros.core.metrics import is_success
from regor_ros.ros.pointcloud import xyz_to_cloud
from regor_ros.tools.pair_client import PairClient, pose_to_matrix


def rss_mib(pid: int) -> float:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def lidar_scan_message(xyz, header, rings=64, columns=2048):
    """An organised 64 x 2048 scan as a LiDAR driver publishes it: x, y, z, intensity, t (float32)
    and ring (uint16) in 32-byte points (4 MiB), the points drawn from a real scan."""
    n = rings * columns
    points = np.repeat(xyz, -(-n // len(xyz)), axis=0)[:n]
    layout = np.dtype({"names": ["x", "y", "z", "intensity", "t", "ring"], "formats": ["<f4"] * 5 + ["<u2"],
                       "offsets": [0, 4, 8, 16, 20, 24], "itemsize": 32})
    data = np.zeros(n, dtype=layout)
    data["x"], data["y"], data["z"] = points.T
    data["intensity"] = 50.0
    data["t"] = np.tile(np.linspace(0.0, 0.1, columns), rings)
    data["ring"] = np.repeat(np.arange(rings), columns)
    fields = [PointField(name=name, offset=int(layout.fields[name][1]),
                         datatype=PointField.UINT16 if name == "ring" else PointField.FLOAT32, count=1)
              for name in layout.names]
    return PointCloud2(header=header, height=rings, width=columns, fields=fields, is_bigendian=False,
                       point_step=32, row_step=32 * columns, data=data.tobytes(), is_dense=True)


def test_every_large_lidar_scan_published_once_per_second_arrives(install, ros):
    """20 scans of 131,072 points (4 MiB each), published once a second by a reliable publisher to
    the node as the README configures it (default best-effort source QoS, the package's Fast DDS
    profile in both processes): each is registered or counted as dropped, none is lost."""
    src, tgt, _, _ = load_pair("lidar_koide_251371071_to_251370668")
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros" / "share" / "regor_ros" / "config" / "outdoor.yaml"),
                       "-p", "mode:=map")
    try:
        assert ros.wait_for_node(TIMEOUT), node.output()
        first = len(ros.statuses)
        ros.publish(target=lidar_scan_message(tgt, ros.header("map")))
        sent = 20
        for _ in range(sent):
            ros.publish(source=lidar_scan_message(src, ros.header("scan")))
            ros.spin_until(lambda: False, 1.0)

        def all_counted():
            if len(ros.statuses) == first:
                return False
            last = ros.statuses[-1]
            return last["source_clouds"] >= sent and last["registrations"] + last["dropped_stale"] >= sent

        ros.spin_until(all_counted, 30.0)
        assert len(ros.statuses) > first, node.output()
        last = ros.statuses[-1]
        print(f"\nlarge scans: {sent} published, {last['source_clouds']} arrived, {last['registrations']} "
              f"registered, {last['dropped_stale']} dropped as stale, {sent - last['source_clouds']} lost")
        assert last["source_clouds"] == sent, last
        assert last["registrations"] + last["dropped_stale"] == sent and last["bad_inputs"] == 0, last
    finally:
        assert node.stop() < 10.0


def hostile_clouds(header):
    """(kind, message) pairs: every way a PointCloud2 can be broken or useless."""
    good = xyz_to_cloud(np.random.default_rng(0).uniform(-1, 1, (100, 3)), header)

    def variant(**changes):
        msg = xyz_to_cloud(np.frombuffer(bytes(good.data), "<f4").reshape(-1, 3), header)
        for key, value in changes.items():
            setattr(msg, key, value)
        return msg

    f32 = PointField.FLOAT32
    yield "data holds", variant(data=bytes(good.data)[:50])
    yield "does not fit in point_step", variant(point_step=4, row_step=400)
    yield "does not fit in point_step", variant(fields=[PointField(name=a, offset=4 * i + 100, datatype=f32, count=1)
                                                      for i, a in enumerate("xyz")])
    yield "only FLOAT32", variant(fields=[PointField(name=a, offset=4 * i, datatype=99, count=1)
                                          for i, a in enumerate("xyz")])
    yield "empty cloud", variant(width=0, row_step=0)
    yield "data holds", variant(width=5000, row_step=60000)
    yield "no x", variant(fields=[])
    yield "NaN or infinite", xyz_to_cloud(np.full((100, 3), np.nan), header)
    yield "too few points", xyz_to_cloud(np.zeros((1, 3)), header)
    yield "beyond", xyz_to_cloud(np.full((100, 3), 1e30), header)


def test_hostile_input_is_skipped_with_a_warning_per_kind(install, ros):
    node = NodeProcess(install, "-p", "source_qos:=reliable")
    try:
        assert ros.wait_for_node(TIMEOUT), node.output()
        kinds = set()
        for _ in range(15):
            for kind, msg in hostile_clouds(ros.header("scan")):
                kinds.add(kind)
                ros.publish(source=msg, target=msg)
                ros.spin_until(lambda: False, 0.01)
        million = xyz_to_cloud(np.ones((1_000_000, 3)), ros.header("map"))
        ros.publish(target=million)
        ros.spin_until(lambda: False, 2.0)
        assert node.proc.poll() is None, node.output()
        src, tgt, T_gt, kind = moved_pair("3dmatch_redkitchen_5_6_ds", 41)
        pose, status = ros.register_pair(src, tgt, TIMEOUT)
        assert pose is not None and is_success(pose_to_matrix(pose), T_gt, kind), status
        # how many reach the worker depends on timing (a newer cloud supersedes one not yet
        # registered), but every kind must have been counted and warned about
        assert status["bad_inputs"] >= len(kinds), status
        log = node.output()
        for text in kinds:
            assert text in log, f"no warning for {text!r}"
        assert "Traceback" not in log
        # throttled: each kind is logged a few times, not once per message
        assert log.count("data holds") < 10
    finally:
        node.stop()


def test_degenerate_and_unrelated_clouds_are_never_published_as_poses(install, ros):
    node = NodeProcess(install)
    try:
        assert ros.wait_for_node(TIMEOUT), node.output()
        rng = np.random.default_rng(5)
        plane = np.c_[rng.uniform(-2, 2, (20000, 2)), np.zeros(20000)]
        line = np.c_[np.linspace(0, 10, 5000), np.zeros((5000, 2))]
        kitchen, _, _, _ = moved_pair("3dmatch_redkitchen_5_6_ds", 42)
        _, hotel, _, _ = load_pair("3dmatch_hotel_umd_8_15_ds")
        cases = {"plane": (plane, plane + [0.3, 0.1, 0]), "line": (line, line),
                 "unrelated rooms": (kitchen, hotel),
                 "random cloud": (kitchen, rng.uniform(hotel.min(0), hotel.max(0), (20000, 3)))}
        for name, (src, tgt) in cases.items():
            pose, status = ros.register_pair(src, tgt, TIMEOUT)
            assert status is not None, (name, node.output())
            assert pose is None and not status["accepted"] and status["reason"], (name, status)
        assert "pose rejected" in node.output()
    finally:
        node.stop()


def test_faults_publishers_restart_map_reframed_parameters_changed(install, ros):
    node = NodeProcess(install, "-p", "mode:=map")
    try:
        assert ros.wait_for_node(TIMEOUT), node.output()
        src, tgt, T_gt, kind = moved_pair("3dmatch_redkitchen_5_6_ds", 43)
        ros.publish(target=xyz_to_cloud(tgt, ros.header("map")))
        # an invalid change mid-run is refused, a valid one is taken
        assert not set_param(ros, "regeneration.stage_seeds", [100]).successful
        assert set_param(ros, "acceptance.min_inliers", 60).successful
        seen = len(ros.poses)
        ros.publish(source=xyz_to_cloud(src, ros.header("scan")))
        assert ros.spin_until(lambda: len(ros.poses) > seen, TIMEOUT), node.output()
        assert is_success(pose_to_matrix(ros.poses[seen]), T_gt, kind)

        # the publishers disappear; a new process-like client comes back with a re-framed map
        rclpy_node = PairClient("regor_test_client_restarted")
        try:
            ros.destroy_publisher(ros.source_pub)
            ros.destroy_publisher(ros.target_pub)
            assert rclpy_node.wait_for_node(TIMEOUT)
            rclpy_node.publish(target=xyz_to_cloud(tgt, rclpy_node.header("map_v2")))
            src2, _, T_gt2, _ = moved_pair("3dmatch_redkitchen_5_6_ds", 44)
            rclpy_node.spin_until(lambda: False, 1.0)
            rclpy_node.publish(source=xyz_to_cloud(src2, rclpy_node.header("scan")))
            assert rclpy_node.spin_until(lambda: rclpy_node.poses, TIMEOUT), node.output()
            pose = rclpy_node.poses[-1]
            assert pose.header.frame_id == "map_v2"
            assert is_success(pose_to_matrix(pose), T_gt2, kind)
        finally:
            rclpy_node.destroy_node()
            ros.source_pub = ros.create_publisher(PointCloud2, "source_cloud", 10)
            ros.target_pub = ros.create_publisher(PointCloud2, "target_cloud", ros.target_qos)
    finally:
        node.stop()
    assert node.proc.returncode == 0, node.output()


def test_sigint_while_registering_exits_cleanly(install, ros):
    """The worker is abandoned, not awaited, and the process exits with 0. The bound is one a
    loaded machine cannot miss (the node waits 0.3 s for the worker); how fast it exits is for a
    benchmark, not a test (1.28 s against a 1 s bound failed on a busy machine)."""
    src, tgt, _, _ = moved_pair("kitti07_submap_1_2", 45)   # skips without the shared data, before any node
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros/share/regor_ros/config/outdoor.yaml"))
    assert ros.wait_for_node(TIMEOUT), node.output()
    ros.publish(xyz_to_cloud(src, ros.header("scan")), xyz_to_cloud(tgt, ros.header("map")))
    ros.spin_until(lambda: False, 1.5)   # the registration of a KITTI submap takes seconds
    took = node.stop()
    print(f"\nSIGINT during registration: exited in {took:.2f} s, code {node.proc.returncode}")
    assert took < 8.0 and node.proc.returncode == 0, node.output()
    assert "Traceback" not in node.output()   # a registration ending meanwhile publishes nothing


def test_load_drops_stale_inputs_and_keeps_memory_and_latency_bounded(install, ros):
    """20 Hz of the largest shared pair for a minute: far faster than registration."""
    node = NodeProcess(install, "--params-file",
                       str(install / "regor_ros/share/regor_ros/config/outdoor.yaml"))
    try:
        assert ros.wait_for_node(TIMEOUT), node.output()
        src, tgt, T_gt, kind = load_pair("lidar_koide_251371071_to_251370668")
        src_msg, tgt_msg = xyz_to_cloud(src, Header()), xyz_to_cloud(tgt, Header())
        poses_before, statuses_before = len(ros.poses), len(ros.statuses)
        published, rss, answers = 0, [], []
        start = time.monotonic()
        stamp_to_mono = {}
        while time.monotonic() - start < 60.0:
            tick = time.monotonic()
            header = ros.header("scan")
            stamp_to_mono[(header.stamp.sec, header.stamp.nanosec)] = tick
            src_msg.header, tgt_msg.header = header, Header(stamp=header.stamp, frame_id="map")
            ros.publish(src_msg, tgt_msg)
            published += 1
            if published % 100 == 0:
                rss.append(rss_mib(node.proc.pid))
                t0 = time.monotonic()
                assert set_param(ros, "max_markers", 100 + published).successful
                answers.append(time.monotonic() - t0)
            ros.spin_until(lambda: False, max(0.0, 0.05 - (time.monotonic() - tick)))
        ros.spin_until(lambda: False, 5.0)
        statuses = ros.statuses[statuses_before:]
        poses = ros.poses[poses_before:]
        assert statuses and poses, node.output()
        final = statuses[-1]
        registration = [s["timings"]["total"] for s in statuses]
        stamps = [(p.header.stamp.sec, p.header.stamp.nanosec) for p in poses]
        latency = [arrived - stamp_to_mono[k]
                   for k, arrived in zip(stamps, ros.pose_arrivals[poses_before:], strict=False) if k in stamp_to_mono]
        print(f"\nload: published {published} pairs in 60 s, {final['registrations']} registered, "
              f"{final['dropped_stale']} stale inputs dropped; registration median "
              f"{np.median(registration):.2f} s (max {max(registration):.2f}); latency median "
              f"{np.median(latency):.2f} s (max {max(latency):.2f}); RSS MiB {[round(r) for r in rss]}; "
              f"parameter answers median {np.median(answers):.3f} s (max {max(answers):.3f})")
        assert final["dropped_stale"] > published // 2
        assert final["registrations"] < published // 4
        # memory: bounded, no growth with the number of inputs after warm-up
        assert max(rss[len(rss) // 2:]) < 1.3 * max(rss[:len(rss) // 2]) + 50
        # no queue: a pose is out at most one registration after its input arrived (plus its own)
        assert max(latency) < 2 * max(registration) + 1.0
        assert all(is_success(pose_to_matrix(p), T_gt, kind) for p in poses[-3:])
        assert max(answers) < 5.0
    finally:
        node.stop()
