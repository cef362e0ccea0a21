"""The installed node as Nav2's lifecycle manager drives it, over DDS: configure loads the map or
fails with the reason, activate registers, load_map swaps maps, and the node never takes its own
pose as a hint."""
import re

import numpy as np
import pytest
from conftest import DATA, load_map_query
from geometry_msgs.msg import PoseWithCovarianceStamped
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav_msgs.srv import LoadMap
from ros_helpers import TIMEOUT, NodeProcess, call
from std_srvs.srv import Trigger

from regor_ros.core.metrics import is_success, rotation_error_deg, translation_error
from regor_ros.ros.pointcloud import xyz_to_cloud
from regor_ros.tools.pair_client import pose_to_matrix

OUTDOOR_ARGS = ("-p", "preset:=outdoor", "-p", "mode:=map", "-p", "map_cache:=false", "-r", "__node:=register_node")


def _node(install, map_file, *extra):
    return NodeProcess(install, *OUTDOOR_ARGS, "-p", f"map_file:={map_file}", *extra)


def _transition(ros, transition_id) -> bool:
    return call(ros, ChangeState, "change_state",
                ChangeState.Request(transition=Transition(id=transition_id))).success


def _state(ros) -> int:
    return call(ros, GetState, "get_state", GetState.Request(), resend_every=10.0).current_state.id


def _relocalize(ros, scan):
    client = ros.create_client(Trigger, "/register_node/relocalize")
    try:
        assert client.wait_for_service(timeout_sec=TIMEOUT)
        future = client.call_async(Trigger.Request())
        ros.spin_until(lambda: False, 1.0)  # the call reaches the node before the scan
        ros.spin_until(lambda: ros.source_pub.get_subscription_count() > 0, TIMEOUT)
        ros.publish(source=xyz_to_cloud(scan, ros.header("livox")))
        assert ros.spin_until(future.done, TIMEOUT)
        return future.result()
    finally:
        ros.destroy_client(client)


def _wait_for_services(ros, node):
    client = ros.create_client(GetState, "/register_node/get_state")
    try:
        assert client.wait_for_service(timeout_sec=TIMEOUT), node.output()
    finally:
        ros.destroy_client(client)


@pytest.fixture(scope="module")
def map_files(tmp_path_factory):
    """The Avia and the MulRan maps as .npy files, and files that are not maps."""
    folder = tmp_path_factory.mktemp("maps")
    files = {}
    for name in ("fastlio_avia_hku2", "scaloam_mulran_kaist03"):
        files[name] = folder / f"{name}.npy"
        np.save(files[name], load_map_query(name, "scan_000005")[1])
    files["trajectory"] = folder / "trajectory.txt"
    files["trajectory"].write_text((DATA / "maps" / "fastlio_avia_hku2" / "map_trajectory.txt").read_text())
    files["random"] = folder / "random.bin"
    files["random"].write_bytes(np.random.default_rng(0).bytes(100_000))
    files["missing"] = folder / "missing.pcd"
    files["empty"] = folder / "empty.npy"
    np.save(files["empty"], np.zeros((0, 3), np.float32))
    return files


@pytest.mark.parametrize("bad, says", [("missing", "no such file"), ("trajectory", "TUM trajectory"),
                                       ("random", "not a point cloud"),
                                       ("empty", "empty.npy: no points (an empty array)")])
def test_a_map_that_is_not_one_fails_configure_with_the_reason(install, ros, map_files, bad, says):
    """Driven by a lifecycle manager: configure fails and the node stays unconfigured. Started
    alone (autostart): it exits non-zero and says why."""
    node = _node(install, map_files[bad], "-p", "autostart:=false")
    try:
        _wait_for_services(ros, node)
        assert _state(ros) == State.PRIMARY_STATE_UNCONFIGURED
        assert not _transition(ros, Transition.TRANSITION_CONFIGURE)
        assert _state(ros) == State.PRIMARY_STATE_UNCONFIGURED
        assert says in node.output()
    finally:
        node.stop()
    alone = _node(install, map_files[bad])
    assert alone.proc.wait(timeout=TIMEOUT) != 0
    assert says in alone.output() and "configure failed" in alone.output()


def test_configure_activate_relocalize_then_load_map_swaps_the_map(install, ros, map_files):
    node = _node(install, map_files["fastlio_avia_hku2"], "-p", "autostart:=false",
                 "-p", "registration:=on_demand", "-p", "relocalize_timeout:=60.0")
    try:
        _wait_for_services(ros, node)
        assert "registration kernels ready" not in node.output()  # compiled or loaded in configure,
        assert _transition(ros, Transition.TRANSITION_CONFIGURE), node.output()  # not on a relocalization
        assert "registration kernels ready" in node.output()
        # the time to ready counts from the process's start, imports included, the map's part named
        assert re.search(r"ready to register [\d.]+ s after the process started \(kernels [\d.]+ s, map [\d.]+ s\)",
                         node.output()), node.output()
        assert _state(ros) == State.PRIMARY_STATE_INACTIVE
        inactive = call(ros, Trigger, "relocalize", Trigger.Request())
        assert not inactive.success and "inactive" in inactive.message
        assert _transition(ros, Transition.TRANSITION_ACTIVATE)
        assert _state(ros) == State.PRIMARY_STATE_ACTIVE
        for name, stale in (("fastlio_avia_hku2", None), ("scaloam_mulran_kaist03", "fastlio_avia_hku2")):
            if stale is not None:
                answer = call(ros, LoadMap, "load_map", LoadMap.Request(map_url=f"file://{map_files[name]}"))
                assert answer.result == LoadMap.Response.RESULT_SUCCESS, node.output()
                failed = call(ros, LoadMap, "load_map", LoadMap.Request(map_url=str(map_files["random"])))
                assert failed.result == LoadMap.Response.RESULT_INVALID_MAP_DATA   # the new map stays
                absent = call(ros, LoadMap, "load_map", LoadMap.Request(map_url=str(map_files["missing"])))
                assert absent.result == LoadMap.Response.RESULT_MAP_DOES_NOT_EXIST
                assert "no such file, the previous map stays" in node.output()
            scan, _, truth = load_map_query(name, "scan_000005")
            seen = len(ros.poses)
            answer = _relocalize(ros, scan)
            assert answer.success, (answer.message, node.output())
            assert ros.spin_until(lambda: len(ros.poses) > seen, 10.0)
            T = pose_to_matrix(ros.poses[-1])
            assert is_success(T, truth, "outdoor"), (name, rotation_error_deg(T, truth), translation_error(T, truth))
            assert ros.statuses[-1]["map_file"] == str(map_files[name])
        assert _transition(ros, Transition.TRANSITION_DEACTIVATE)
        assert "inactive: not registering" in node.output()
        assert _transition(ros, Transition.TRANSITION_CLEANUP)
        assert _state(ros) == State.PRIMARY_STATE_UNCONFIGURED
    finally:
        node.stop()


def test_the_node_never_takes_its_own_pose_as_a_hint(install, ros, map_files):
    """pose_with_covariance remapped to /initialpose while initial_guess listens there (both are
    suggested for Nav2): the node hears its own pose and must not narrow the next search to it."""
    node = _node(install, map_files["fastlio_avia_hku2"], "-r", "pose_with_covariance:=/initialpose",
                 "-r", "initial_guess:=/initialpose")
    heard = []
    subscription = ros.create_subscription(PoseWithCovarianceStamped, "/initialpose", heard.append, 10)
    try:
        assert ros.spin_until(lambda: ros.source_pub.get_subscription_count() > 0, TIMEOUT), node.output()
        ros.spin_until(lambda: False, 1.0)
        for query in ("scan_000005", "scan_000057"):
            scan = load_map_query("fastlio_avia_hku2", query)[0]
            seen = len(ros.statuses)
            ros.publish(source=xyz_to_cloud(scan, ros.header("livox")))
            assert ros.spin_until(lambda: len(ros.statuses) > seen, TIMEOUT), node.output()
            assert ros.statuses[-1]["accepted"], ros.statuses[-1]["reason"]
            assert ros.spin_until(lambda: heard, 5.0)   # the pose went out on /initialpose
            assert ros.statuses[-1]["search_region"] is None
    finally:
        ros.destroy_subscription(subscription)
        node.stop()
