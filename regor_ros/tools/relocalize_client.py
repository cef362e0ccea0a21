"""regor-relocalize: drive a running register_node without the ros2 command line (the pip route).

What ``ros2 service call`` and ``ros2 lifecycle set`` do on a ROS install: ask the node to
relocalize (optionally publishing a scan from a file once the call is under way, for a robot
whose driver is not running), swap its map, or move it through its lifecycle. Prints the answer;
the exit status is 0 when the node said yes.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from nav_msgs.srv import LoadMap
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from ..io.cloud_io import CloudFileError, read_cloud
from ..ros.messages import matrix_from_pose
from ..ros.pointcloud import xyz_to_cloud

TRANSITIONS = {"configure": Transition.TRANSITION_CONFIGURE, "activate": Transition.TRANSITION_ACTIVATE,
               "deactivate": Transition.TRANSITION_DEACTIVATE, "cleanup": Transition.TRANSITION_CLEANUP}
SETTLE_S = 1.0  # the call reaches the node before the scan is published
EPILOG = """examples:
  regor-relocalize --scan scan.npy --frame lidar     # relocalize on this scan; prints the verdict and the pose
  regor-relocalize                                   # relocalize on the next scan the driver publishes
  regor-relocalize --load-map /maps/site.pcd?trajectory=/maps/site_tum.txt
  regor-relocalize --transition deactivate"""


class Client(Node):
    def __init__(self, node: str):
        super().__init__("regor_relocalize")
        self.node = node.rstrip("/")
        self.poses: list[PoseStamped] = []
        self.create_subscription(PoseStamped, "pose", self.poses.append, 10)
        self.scans = self.create_publisher(PointCloud2, "source_cloud", 10)

    def call(self, srv_type, name: str, request, timeout: float, find_within: float, while_waiting=None):
        client: Any = self.create_client(srv_type, f"{self.node}/{name}")
        if not self._found(client, find_within, timeout):
            raise TimeoutError(f"no service {self.node}/{name} within {find_within:g} s: is register_node running "
                               "(and configured), with this ROS_DOMAIN_ID?")
        future = client.call_async(request)
        if while_waiting is not None:
            rclpy.spin_until_future_complete(self, future, timeout_sec=SETTLE_S)
            while_waiting()
        rclpy.spin_until_future_complete(self, future, timeout_sec=timeout)
        if not future.done():
            raise TimeoutError(f"{self.node}/{name} did not answer within {timeout:g} s")
        return future.result()


    def _found(self, client, find_within: float, timeout: float) -> bool:
        """Whether the service appears: within ``find_within`` seconds, or within ``timeout`` once the
        node itself is seen (a node that is starting: its kernels and map come before its services)."""
        start = time.monotonic()
        while not client.wait_for_service(timeout_sec=0.5):
            waited = time.monotonic() - start
            starting = any(f"{namespace.rstrip('/')}/{name}" == self.node
                           for name, namespace in self.get_node_names_and_namespaces())
            if waited > (timeout if starting else find_within):
                return False
        return True


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-relocalize", description=__doc__.split("\n\n")[0], epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scan", type=Path, help="publish this cloud file on source_cloud once the relocalize "
                                                  "call is under way (.npy, .pcd, .ply, .xyz, .bin; default: "
                                                  "none, the driver's next scan)")
    parser.add_argument("--frame", default="sensor", help="frame_id of the published scan (default: %(default)s)")
    parser.add_argument("--load-map", metavar="MAP_URL", help="instead: swap the node's map (a path, "
                        "with ?trajectory=PATH for its TUM trajectory)")
    parser.add_argument("--transition", choices=sorted(TRANSITIONS), help="instead: a lifecycle transition")
    parser.add_argument("--node", default="/register_node", help="the node's name (default: %(default)s)")
    parser.add_argument("--timeout", type=float, default=60.0,
                        help="seconds to wait for the node's answer (default: %(default)s)")
    parser.add_argument("--find-within", type=float, default=5.0,
                        help="seconds to wait for the node to appear; a node that is starting is waited for up "
                             "to --timeout (default: %(default)s)")
    args = parser.parse_args(argv)
    try:
        scan = read_cloud(args.scan) if args.scan else None
    except CloudFileError as exc:
        print(f"regor-relocalize: {exc}", file=sys.stderr)
        return 2

    rclpy.init()
    client = Client(args.node)
    try:
        if args.transition:
            ok = client.call(ChangeState, "change_state",
                             ChangeState.Request(transition=Transition(id=TRANSITIONS[args.transition])),
                             args.timeout, args.find_within).success
            print(f"{args.transition}: {'done' if ok else 'refused (the node log says why)'}")
            return 0 if ok else 1
        if args.load_map:
            result = client.call(LoadMap, "load_map", LoadMap.Request(map_url=args.load_map), args.timeout,
                                 args.find_within).result
            names = {LoadMap.Response.RESULT_SUCCESS: "map loaded",
                     LoadMap.Response.RESULT_MAP_DOES_NOT_EXIST: "no such map file",
                     LoadMap.Response.RESULT_INVALID_MAP_DATA: "not usable as a map (the node log says why)"}
            print(f"load_map {args.load_map}: {names.get(result, f'failed (result {result})')}")
            return 0 if result == LoadMap.Response.RESULT_SUCCESS else 1
        seen = len(client.poses)

        def publish():
            header = Header(stamp=client.get_clock().now().to_msg(), frame_id=args.frame)
            client.scans.publish(xyz_to_cloud(np.asarray(scan), header))

        answer = client.call(Trigger, "relocalize", Trigger.Request(), args.timeout, args.find_within,
                             publish if scan is not None else None)
        print(f"relocalize: {'accepted' if answer.success else 'not accepted'}: {answer.message}")
        if answer.success:
            deadline = client.get_clock().now().nanoseconds + 5e9
            while len(client.poses) <= seen and client.get_clock().now().nanoseconds < deadline:
                rclpy.spin_once(client, timeout_sec=0.1)
            if len(client.poses) > seen:
                pose = client.poses[-1]
                np.set_printoptions(precision=4, suppress=True)
                print(f"pose in '{pose.header.frame_id}':\n{matrix_from_pose(pose.pose)}")
        return 0 if answer.success else 1
    except TimeoutError as exc:
        print(f"regor-relocalize: {exc}", file=sys.stderr)
        return 2
    finally:
        client.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())
