"""Publish a scan pair to a running register_node and report the pose it answers with.

Used by the demo and the integration tests:
``regor-pair-client SRC.npy TGT.npy --ground-truth gt.txt --rotate 7`` publishes the two clouds
on source_cloud / target_cloud and prints the received pose with its error against the truth.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import PoseArray, PoseStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header, String
from visualization_msgs.msg import MarkerArray

from ..ros.messages import matrix_from_pose, stamp_seconds
from ..ros.pointcloud import xyz_to_cloud

DISCOVERY_SETTLE_S = 1.0
RETRY_S = 10.0


def pose_to_matrix(msg: PoseStamped) -> np.ndarray:
    return matrix_from_pose(msg.pose)


class PairClient(Node):
    """Publishes clouds to register_node's inputs and records what it publishes."""

    def __init__(self, name: str = "regor_pair_client"):
        super().__init__(name)
        self.target_qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.source_pub = self.create_publisher(PointCloud2, "source_cloud", 10)
        self.target_pub = self.create_publisher(PointCloud2, "target_cloud", self.target_qos)
        self.poses: list[PoseStamped] = []
        self.pose_arrivals: list[float] = []  # time.monotonic() when each pose arrived
        self.markers: list[MarkerArray] = []
        self.statuses: list[dict] = []
        self.create_subscription(PoseStamped, "pose", self._on_pose, 10)
        self.create_subscription(MarkerArray, "correspondences", self.markers.append, 10)
        self.candidates: list[PoseArray] = []
        self.create_subscription(PoseArray, "candidates", self.candidates.append, 10)
        self.create_subscription(String, "status", lambda m: self.statuses.append(json.loads(m.data)), 10)

    def _on_pose(self, msg: PoseStamped) -> None:
        self.poses.append(msg)
        self.pose_arrivals.append(time.monotonic())

    def header(self, frame: str) -> Header:
        return Header(stamp=self.get_clock().now().to_msg(), frame_id=frame)

    def spin_until(self, condition, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            rclpy.spin_once(self, timeout_sec=0.05)
        return condition()

    # not rclpy's (Jazzy on) wait_for_node(name): register_node's subscription, within timeout
    def wait_for_node(self, timeout: float) -> bool:  # type: ignore[override]
        found = self.spin_until(lambda: self.source_pub.get_subscription_count() > 0
                                and self.target_pub.get_subscription_count() > 0, timeout)
        self.spin_until(lambda: False, DISCOVERY_SETTLE_S)  # let the node match us too
        return found

    def publish(self, source: PointCloud2 | None = None, target: PointCloud2 | None = None):
        if target is not None:
            self.target_pub.publish(target)
        if source is not None:
            self.source_pub.publish(source)

    def register_pair(self, src: np.ndarray, tgt: np.ndarray, timeout: float,
                      source_frame: str = "scan", target_frame: str = "map"):
        """Publish both clouds (again every RETRY_S while unanswered) until the status of this
        pair arrives; returns (pose or None, status). The node pairs the newest source with the
        newest target, so an answer is recognised by both stamps, never by its arrival: one for
        an earlier pair, or for an earlier source with this target, may still be on its way."""
        source = xyz_to_cloud(src, self.header(source_frame))
        target = xyz_to_cloud(tgt, self.header(target_frame))
        stamps = (stamp_seconds(source.header), stamp_seconds(target.header))
        status = None
        deadline = time.monotonic() + timeout
        while status is None and time.monotonic() < deadline:
            self.publish(source, target)
            self.spin_until(lambda: self._status_of(stamps) is not None,
                            min(RETRY_S, deadline - time.monotonic()))
            status = self._status_of(stamps)
        if status is None or not status["accepted"]:
            return None, status
        self.spin_until(lambda: self._pose_of(source.header) is not None, 5.0)
        return self._pose_of(source.header), status

    def _status_of(self, stamps: tuple[float, float]) -> dict | None:
        return next((s for s in self.statuses if (s["source_stamp"], s["target_stamp"]) == stamps), None)

    def _pose_of(self, header: Header) -> PoseStamped | None:
        return next((p for p in self.poses if p.header.stamp == header.stamp), None)


def verdict_line(status: dict) -> str:
    """The status message's verdict in one short line (--status prints all of it)."""
    evidence = status.get("evidence") or {}
    measured = status["figures"]
    worst = measured.get("worst_free_space")
    figures = [f"{measured['num_inliers']:.0f} inliers", f"{measured['feature_inliers']:.0f} feature matches agree"]
    if evidence.get("log10_false_alarms") is not None:
        figures.append(f"10^{evidence['log10_false_alarms']:.1f} false alarms")
    if worst is not None:
        figures.append(f"{100 * worst:.1f} % in free space")
    verdict = "published" if status["accepted"] else "withheld"
    return f"verdict: {verdict} ({', '.join(figures)}; --status prints every figure)"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-pair-client", description=__doc__.split("\n\n")[0],
                                     epilog="example:\n  regor-pair-client demo/src.npy demo/tgt.npy "
                                            "--ground-truth demo/gt.txt --rotate 7",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("source", type=Path, help="source cloud, (N, 3) .npy")
    parser.add_argument("target", type=Path, help="target cloud, (N, 3) .npy")
    parser.add_argument("--ground-truth", type=Path, help="4x4 T_target_source to compare with")
    parser.add_argument("--rotate", type=int, metavar="SEED",
                        help="turn the source by a random rotation about its sensor first (truth "
                             "adjusted); it stays in its sensor frame, as the node's default viewpoint assumes")
    parser.add_argument("--timeout", type=float, default=120.0,
                        help="seconds to wait for the node (default: %(default)s)")
    parser.add_argument("--status", action="store_true",
                        help="print the node's whole status message (JSON: every figure of the verdict)")
    args = parser.parse_args(argv)
    from ..core import random_rigid_motion, rotation_error_deg, translation_error  # scipy: after parsing

    src, tgt = np.load(args.source), np.load(args.target)
    T_gt = np.loadtxt(args.ground_truth) if args.ground_truth else None
    if args.rotate is not None:
        M = random_rigid_motion(args.rotate, max_translation=0.0)
        src = src @ M[:3, :3].T + M[:3, 3]
        T_gt = T_gt @ np.linalg.inv(M) if T_gt is not None else None

    rclpy.init()
    client = PairClient()
    try:
        if not client.wait_for_node(args.timeout):
            print("no register_node is listening on source_cloud / target_cloud", file=sys.stderr)
            return 2
        print(f"published source ({len(src)} points) and target ({len(tgt)} points); waiting for the pose")
        pose, status = client.register_pair(src, tgt, args.timeout)
    finally:
        client.destroy_node()
        rclpy.try_shutdown()
    if status is None:
        print("no answer from register_node", file=sys.stderr)
        return 2
    print(json.dumps(status) if args.status else verdict_line(status))
    if pose is None:
        print(f"pose rejected by the quality gate: {status['reason']}")
        return 1
    T = pose_to_matrix(pose)
    np.set_printoptions(precision=4, suppress=True)
    print(f"pose of '{status['source_frame']}' in '{pose.header.frame_id}' (T_target_source):\n{T}")
    if T_gt is not None:
        re, te = rotation_error_deg(T, T_gt), translation_error(T, T_gt)
        print(f"error against ground truth: rotation {re:.2f} deg, translation {100 * te:.1f} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
