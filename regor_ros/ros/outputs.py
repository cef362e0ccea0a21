"""What register_node publishes: each registration's pose, covariance, correspondences, candidates,
status and aligned cloud, the watchdog's checks, and the map as it uses it (latched, for RViz).

Lifecycle publishers, made in configure and destroyed in cleanup. Every publish is dropped when
it fails because the context is shut down: SIGINT shuts it down (rclpy's handler) before the node
stops its worker, which may be publishing.
"""
from __future__ import annotations

import json
from collections import deque

from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header, String
from visualization_msgs.msg import MarkerArray

from ..core import PreparedCloud, transform_points
from . import messages
from .input_qos import fixed_profile
from .pointcloud import xyz_to_cloud
from .report import Outcome
from .watchdog import Check

OWN_POSES_KEPT = 20  # poses published, remembered so that one coming back as a hint is recognised


class Outputs:
    """The node's publishers; ``settings`` gives the settings in force when a registration goes out."""

    pose: LifecyclePublisher   # these seven: made in configure (make), destroyed in cleanup (destroy)
    pose_with_covariance: LifecyclePublisher
    correspondences: LifecyclePublisher
    candidates: LifecyclePublisher
    status: LifecyclePublisher
    aligned_cloud: LifecyclePublisher
    map_cloud: LifecyclePublisher

    def __init__(self, node: LifecycleNode, settings):
        self.node, self.settings = node, settings
        self._made: list[LifecyclePublisher] = []
        self._own_poses: deque[tuple] = deque(maxlen=OWN_POSES_KEPT)  # (stamp, position) of poses published

    def make(self) -> None:
        def publisher(msg_type, topic: str, qos) -> LifecyclePublisher:
            self._made.append(self.node.create_lifecycle_publisher(msg_type, topic, qos))
            return self._made[-1]

        self.pose = publisher(PoseStamped, "pose", 10)
        self.pose_with_covariance = publisher(PoseWithCovarianceStamped, "pose_with_covariance", 10)
        self.correspondences = publisher(MarkerArray, "correspondences", 10)
        self.candidates = publisher(PoseArray, "candidates", 10)
        self.status = publisher(String, "status", 10)
        self.aligned_cloud = publisher(PointCloud2, "aligned_cloud", 1)
        self.map_cloud = publisher(PointCloud2, "map_cloud", fixed_profile("transient_local"))

    def destroy(self) -> None:
        for made in reversed(self._made):
            self.node.destroy_lifecycle_publisher(made)
        self._made = []

    def is_own(self, msg: PoseWithCovarianceStamped) -> bool:
        """Whether a pose that arrived (initial_guess) is one this node published."""
        return messages.pose_key(msg) in self._own_poses

    def while_up(self, publish):
        """``publish``, dropped when it fails because the context is shut down."""
        def guarded(*args) -> None:
            try:
                publish(*args)
            except Exception:
                if self.node.context.ok():
                    raise
        return guarded

    def outcome(self, outcome: Outcome) -> None:
        """A registration's status, correspondences and candidates, and its pose when it goes out."""
        result, settings = outcome.result, self.settings()
        header = messages.header_at(outcome.source.stamp_ns, outcome.target_frame)
        self.status.publish(messages.status_message(result, outcome.status))
        self.correspondences.publish(messages.correspondence_markers(result, header, settings.max_markers,
                                                                     settings.marker_line_width))
        self.candidates.publish(messages.candidate_poses(result, header, settings.max_candidates,
                                                         outcome.T_sensor_base))
        if outcome.pose is None:
            return
        self.pose.publish(messages.pose_stamped(outcome.pose.transform, header))
        own = messages.pose_with_covariance(outcome.pose.transform, outcome.pose.covariance, header)
        self._own_poses.append(messages.pose_key(own))
        self.pose_with_covariance.publish(own)
        if settings.publish_aligned_cloud:
            self.aligned_cloud.publish(xyz_to_cloud(transform_points(result.transform, outcome.source.points),
                                                    header))

    def check(self, check: Check) -> None:
        """The watchdog's verdict on the stack's pose, on status (its diagnostics go with the node's)."""
        self.status.publish(String(data=json.dumps(check.as_dict())))

    def map(self, prepared: PreparedCloud, frame: str) -> None:
        """The map as the node uses it (downsampled, ground kept), latched for RViz."""
        assert prepared.map_view is not None, "a map is prepared with its view"
        self.map_cloud.publish(xyz_to_cloud(prepared.map_view.surface,
                                            Header(stamp=self.node.get_clock().now().to_msg(), frame_id=frame)))
