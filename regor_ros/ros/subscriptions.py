"""What register_node listens to, handed to the localizer as arrays: the clouds (their QoS following
what the publishers offer), odometry, the IMU, initial guesses, the stack's tracked pose and the
watchdog's timer. Made in configure, destroyed in cleanup."""
from __future__ import annotations

from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.lifecycle import LifecycleNode
from sensor_msgs.msg import Imu, PointCloud2

from ..core import RegistrationError
from . import messages
from .initial_guess import region_of_guess
from .input_qos import InputSubscription, fixed_profile, stream_profile
from .localizer import Localizer
from .outputs import Outputs
from .pointcloud import cloud_to_xyz
from .source_context import Hint
from .watchdog import TrackedPose

QOS_CHECK_PERIOD_S = 0.5  # how often auto QoS inputs look at their publishers


class Subscriptions:
    """The node's inputs; ``outputs`` tells its own poses from a hint."""

    def __init__(self, node: LifecycleNode, localizer: Localizer, outputs: Outputs):
        self.node, self.localizer, self.outputs = node, localizer, outputs
        self.clouds: dict[str, InputSubscription] = {}
        self._made: list = []   # (destroy, entity)

    def make(self, settings) -> None:
        node = self.node

        def keep(destroy, entity):
            self._made.append((destroy, entity))

        def subscription(msg_type, topic: str, callback, qos):
            keep(node.destroy_subscription, node.create_subscription(msg_type, topic, callback, qos))

        self.clouds = {which: InputSubscription(node, PointCloud2, f"{which}_cloud",
                                                lambda msg, which=which: self._cloud(which, msg),
                                                getattr(settings, f"{which}_qos"))
                       for which in ("source", "target") if which == "source" or not settings.map_file}
        for cloud in self.clouds.values():
            keep(lambda s: s.destroy(), cloud)
        self.follow_publishers()
        keep(node.destroy_timer, node.create_timer(QOS_CHECK_PERIOD_S, self.follow_publishers))
        subscription(PoseWithCovarianceStamped, "initial_guess", self._initial_guess, fixed_profile("reliable"))
        subscription(Odometry, "odometry", self._odometry, stream_profile(100))   # 100 Hz odometry
        if settings.imu_topic:  # the source's up, for the gravity prior
            subscription(Imu, settings.imu_topic, self._imu, stream_profile(200))
        if settings.verify_rate:  # the watchdog: the stack's pose, checked at verify_rate
            tracked = Odometry if settings.tracked_pose_type == "odometry" else PoseWithCovarianceStamped
            subscription(tracked, "tracked_pose", self._tracked_pose, stream_profile(100))
            keep(node.destroy_timer, node.create_timer(1.0 / settings.verify_rate, self.localizer.request_check))

    def destroy(self) -> None:
        for destroy, entity in reversed(self._made):
            destroy(entity)
        self._made, self.clouds = [], {}

    def follow_publishers(self) -> None:
        """Auto QoS clouds: match what their publishers offer now (and say so in /diagnostics)."""
        for which, cloud in self.clouds.items():
            cloud.update()
            self.localizer.report.health.inputs[f"{which}_qos"] = cloud.state()

    def _cloud(self, which: str, msg: PointCloud2) -> None:
        localizer = self.localizer
        if not localizer.shared.active:  # inactive: inputs are not taken (a lifecycle node's contract)
            return
        try:
            points = cloud_to_xyz(msg)
        except RegistrationError as exc:
            localizer.report.bad_input(f"{which}_cloud skipped: {exc}")
            return
        localizer.store(which, msg.header.frame_id, messages.stamp_nanoseconds(msg.header), points)

    def _odometry(self, msg: Odometry) -> None:
        """The scan frame's pose in the odometry frame at the message's stamp."""
        pose = messages.matrix_from_pose(msg.pose.pose) @ self.localizer.shared.settings.odometry_extrinsic()
        self.localizer.context.add_odometry(messages.stamp_seconds(msg.header), pose)

    def _tracked_pose(self, msg) -> None:
        self.localizer.track_pose(TrackedPose(messages.stamp_seconds(msg.header), msg.header.frame_id,
                                              messages.matrix_from_pose(msg.pose.pose)))

    def _imu(self, msg: Imu) -> None:
        self.localizer.context.add_imu(*messages.imu_reading(msg))

    def _initial_guess(self, msg: PoseWithCovarianceStamped) -> None:
        """A hint, unless it is one of this node's own poses come back (pose_with_covariance remapped
        to /initialpose: it would narrow the search to wherever the last pose was, right or wrong)."""
        if self.outputs.is_own(msg):
            return
        settings = self.localizer.shared.settings
        self.localizer.context.set_hint(Hint(msg.header.frame_id, region_of_guess(
            msg, settings.initial_guess_sigmas, settings.initial_guess_min_radius,
            settings.initial_guess_max_radius)))
        self.node.get_logger().info(
            f"initial guess received: ({msg.pose.pose.position.x:.1f}, {msg.pose.pose.position.y:.1f}, "
            f"{msg.pose.pose.position.z:.1f}) in '{msg.header.frame_id}'; in force until a pose is accepted")
