"""register_node: Regor registration of two PointCloud2 topics, published as a pose.

A lifecycle node, as Nav2 manages them: configure loads the map file (or fails with the reason),
activate starts registering and publishing, deactivate stops, cleanup releases the map and every
entity; with ``autostart`` (the default) it configures and activates itself. The node is the ROS
side (lifecycle, parameters, entities, messages); the work (inputs, map, the worker thread) is
ros/localizer.py's, so the executor keeps answering parameters and services while it registers.
"""
from __future__ import annotations

import json
from collections import deque

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from nav_msgs.srv import LoadMap
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import Imu, PointCloud2
from std_msgs.msg import Header, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from ..core import ConfigError, PreparedCloud, RegistrationError, transform_points
from . import messages
from .diagnostics import diagnostic_array, seconds_since_process_start
from .initial_guess import region_of_guess
from .input_qos import InputSubscription, fixed_profile, stream_profile
from .localizer import Hint, Localizer, Outcome
from .parameters import apply_changes, declare_parameters
from .pointcloud import cloud_to_xyz, xyz_to_cloud
from .spin import PoolExecutor, spin
from .transport import profile_variable, use_large_data_profile
from .watchdog import Check, TrackedPose

STOP_WAIT_S = 0.3  # how long a stop waits for the worker (a registration or map preparation under way is abandoned)
QOS_CHECK_PERIOD_S = 0.5  # how often auto QoS inputs look at their publishers
OWN_POSES_KEPT = 20  # poses published, remembered so that one coming back as a hint is recognised


class RegisterNode(LifecycleNode):
    pose_pub: LifecyclePublisher   # these seven: created in configure, destroyed in cleanup
    pose_cov_pub: LifecyclePublisher
    marker_pub: LifecyclePublisher
    candidates_pub: LifecyclePublisher
    status_pub: LifecyclePublisher
    aligned_pub: LifecyclePublisher
    map_pub: LifecyclePublisher

    def __init__(self):
        super().__init__("register_node")
        config, settings = declare_parameters(self)
        self.localizer = Localizer(config, settings, self.get_logger(), self._while_up(self._publish_outcome),
                                   self._while_up(self._publish_map), self._while_up(self._publish_check))
        self.health = self.localizer.health   # the one Health of the node's life, the localizer's to update
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._entities = []      # (destroy, entity) of what configure created, for cleanup
        self.inputs: dict[str, InputSubscription] = {}
        self._own_poses = deque(maxlen=OWN_POSES_KEPT)  # (stamp, position) of poses published
        # /diagnostics from the start: a node waiting for its lifecycle manager, or whose
        # configure failed, says so
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if settings.diagnostics_period > 0:
            self.create_timer(settings.diagnostics_period, self._publish_diagnostics)

    # --- lifecycle ---

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """The kernels and the map file (Localizer.configure: a map that cannot be used fails with
        the reason), then the inputs, outputs and the worker."""
        try:
            kernels_s = self.localizer.configure()
        except RegistrationError as exc:
            self.health.lifecycle = f"configure failed: map_file not usable: {exc}"
            self.get_logger().error(self.health.lifecycle)
            return TransitionCallbackReturn.FAILURE
        config, settings = self.localizer.config, self.localizer.settings
        self._create_entities(settings)
        self.localizer.start()
        self.health.lifecycle = "inactive"
        self.health.ready_after_s = seconds_since_process_start()
        self.get_logger().info(
            f"configured: mode={settings.mode}, voxel={config.features.voxel_size} m; "
            f"listening on {self.resolve_topic_name('source_cloud')}; the target from "
            f"{settings.map_file or self.resolve_topic_name('target_cloud')}")
        self.get_logger().info(self.health.ready_line(kernels_s))
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        super().on_activate(state)  # the lifecycle publishers
        self.health.lifecycle = "active"
        self.localizer.set_active(True)
        self.get_logger().info("active: registering")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.localizer.set_active(False)
        self.health.lifecycle = "inactive"
        self.get_logger().info("inactive: not registering (activate resumes; the map stays loaded)")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.localizer.stop(STOP_WAIT_S)
        self._destroy_entities()
        self.localizer.release()
        self.health.lifecycle = "unconfigured"
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.localizer.stop(STOP_WAIT_S)
        self._destroy_entities()
        self.health.lifecycle = "finalized"
        return TransitionCallbackReturn.SUCCESS

    def _create_entities(self, settings) -> None:
        def keep(destroy, entity):
            self._entities.append((destroy, entity))
            return entity

        def publisher(msg_type, topic: str, qos) -> LifecyclePublisher:
            return keep(self.destroy_lifecycle_publisher, self.create_lifecycle_publisher(msg_type, topic, qos))

        def subscription(msg_type, topic: str, callback, qos, **kwargs):
            keep(self.destroy_subscription, self.create_subscription(msg_type, topic, callback, qos, **kwargs))

        self.inputs = {which: InputSubscription(self, PointCloud2, f"{which}_cloud",
                                                lambda msg, which=which: self._store(which, msg),
                                                getattr(settings, f"{which}_qos"))
                       for which in ("source", "target") if which == "source" or not settings.map_file}
        for input_subscription in self.inputs.values():
            keep(lambda s: s.destroy(), input_subscription)
        self._follow_publishers()
        keep(self.destroy_timer, self.create_timer(QOS_CHECK_PERIOD_S, self._follow_publishers))
        subscription(PoseWithCovarianceStamped, "initial_guess", self._on_initial_guess, fixed_profile("reliable"))
        subscription(Odometry, "odometry", self._on_odometry, stream_profile(100))   # 100 Hz odometry
        if settings.imu_topic:  # the source's up, for the gravity prior
            subscription(Imu, settings.imu_topic, self._on_imu, stream_profile(200))
        if settings.verify_rate:  # the watchdog: the stack's pose, checked at verify_rate
            tracked = Odometry if settings.tracked_pose_type == "odometry" else PoseWithCovarianceStamped
            subscription(tracked, "tracked_pose", self._on_tracked_pose, stream_profile(100))
            keep(self.destroy_timer, self.create_timer(1.0 / settings.verify_rate, self.localizer.request_check))
        # their own callback groups: a call waits for a registration or a map while scans keep arriving
        keep(self.destroy_service, self.create_service(Trigger, "~/relocalize", self._on_relocalize,
                                                       callback_group=MutuallyExclusiveCallbackGroup()))
        keep(self.destroy_service, self.create_service(LoadMap, "~/load_map", self._on_load_map,
                                                       callback_group=MutuallyExclusiveCallbackGroup()))
        self.pose_pub = publisher(PoseStamped, "pose", 10)
        self.pose_cov_pub = publisher(PoseWithCovarianceStamped, "pose_with_covariance", 10)
        self.marker_pub = publisher(MarkerArray, "correspondences", 10)
        self.candidates_pub = publisher(PoseArray, "candidates", 10)
        self.status_pub = publisher(String, "status", 10)
        self.aligned_pub = publisher(PointCloud2, "aligned_cloud", 1)
        self.map_pub = publisher(PointCloud2, "map_cloud", fixed_profile("transient_local"))

    def _destroy_entities(self) -> None:
        for destroy, entity in reversed(self._entities):
            destroy(entity)
        self._entities = []

    # --- parameters ---

    def _on_set_parameters(self, params) -> SetParametersResult:
        try:
            self.localizer.change(lambda config, settings: apply_changes(
                config, settings, {p.name: p.value for p in params}))
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _follow_publishers(self) -> None:
        for which, input_subscription in self.inputs.items():
            input_subscription.update()
            self.health.inputs[f"{which}_qos"] = input_subscription.state()

    def _publish_diagnostics(self) -> None:
        with self.localizer.lock:
            array = diagnostic_array(self.health, self.get_fully_qualified_name(),
                                     self.get_clock().now().to_msg())
        self.diagnostics_pub.publish(array)

    # --- inputs: messages to arrays, for the localizer ---

    def _store(self, which: str, msg: PointCloud2) -> None:
        if not self.localizer.active:  # inactive: inputs are not taken (a lifecycle node's contract)
            return
        try:
            points = cloud_to_xyz(msg)
        except RegistrationError as exc:
            self.localizer.bad_input(f"{which}_cloud skipped: {exc}")
            return
        self.localizer.store(which, msg.header, messages.stamp_seconds(msg.header), points)

    def _on_odometry(self, msg: Odometry) -> None:
        """The scan frame's pose in the odometry frame at the message's stamp."""
        pose = messages.matrix_from_pose(msg.pose.pose) @ self.localizer.settings.odometry_extrinsic()
        self.localizer.add_odometry(messages.stamp_seconds(msg.header), pose)

    def _on_tracked_pose(self, msg) -> None:
        self.localizer.track_pose(TrackedPose(messages.stamp_seconds(msg.header), msg.header.frame_id,
                                              messages.matrix_from_pose(msg.pose.pose)))

    def _on_imu(self, msg: Imu) -> None:
        self.localizer.add_imu(*messages.imu_reading(msg))

    def _on_initial_guess(self, msg: PoseWithCovarianceStamped) -> None:
        """A hint, unless it is one of this node's own poses come back (pose_with_covariance remapped
        to /initialpose: it would narrow the search to wherever the last pose was, right or wrong)."""
        if messages.pose_key(msg) in self._own_poses:
            return
        settings = self.localizer.settings
        self.localizer.set_hint(Hint(msg.header.frame_id, region_of_guess(
            msg, settings.initial_guess_sigmas, settings.initial_guess_min_radius,
            settings.initial_guess_max_radius)))
        self.get_logger().info(
            f"initial guess received: ({msg.pose.pose.position.x:.1f}, {msg.pose.pose.position.y:.1f}, "
            f"{msg.pose.pose.position.z:.1f}) in '{msg.header.frame_id}'; in force until a pose is accepted")

    # --- services ---

    def _on_relocalize(self, request, response):
        """Answer with the registration of the next source: its verdict and the reason."""
        answer = self.localizer.relocalize()
        response.success, response.message = answer.accepted, answer.text
        return response

    def _on_load_map(self, request, response):
        """Swap the map for another file (Localizer.use_map_url); the old one stays until it is ready or if it fails."""
        if self.localizer.settings.mode != "map":
            response.result = LoadMap.Response.RESULT_UNDEFINED_FAILURE
            self.get_logger().error("load_map: the node is in pairs mode (mode:=map loads maps)")
            return response
        try:
            self.localizer.use_map_url(request.map_url)
            response.result = LoadMap.Response.RESULT_SUCCESS
        except FileNotFoundError as exc:
            response.result = LoadMap.Response.RESULT_MAP_DOES_NOT_EXIST
            self.get_logger().error(f"load_map: no such file, the previous map stays: {exc}")
        except RegistrationError as exc:
            response.result = LoadMap.Response.RESULT_INVALID_MAP_DATA
            self.get_logger().error(f"load_map: map not usable, the previous one stays: {exc}")
        return response

    # --- outputs ---

    def _while_up(self, publish):
        """``publish``, dropped when it fails because the context is shut down: SIGINT shuts it down
        (rclpy's handler) before the node stops its worker, which may be publishing."""
        def guarded(*args) -> None:
            try:
                publish(*args)
            except Exception:
                if self.context.ok():
                    raise
        return guarded

    def _publish_outcome(self, outcome: Outcome) -> None:
        """A registration's status, correspondences and candidates, and its pose when it goes out."""
        result, settings = outcome.result, self.localizer.settings
        header = Header(stamp=outcome.source.header.stamp, frame_id=outcome.target_frame)
        self.status_pub.publish(messages.status_message(result, outcome.status))
        self.marker_pub.publish(messages.correspondence_markers(result, header, settings.max_markers,
                                                                settings.marker_line_width))
        self.candidates_pub.publish(messages.candidate_poses(result, header, settings.max_candidates,
                                                             outcome.sensor_to_base))
        if outcome.pose is None:
            return
        self.pose_pub.publish(messages.pose_stamped(outcome.pose.transform, header))
        own = messages.pose_with_covariance(outcome.pose.transform, outcome.pose.covariance, header)
        self._own_poses.append(messages.pose_key(own))
        self.pose_cov_pub.publish(own)
        if settings.publish_aligned_cloud:
            self.aligned_pub.publish(xyz_to_cloud(transform_points(result.transform, outcome.source.points),
                                                  header))

    def _publish_check(self, check: Check) -> None:
        """The watchdog's verdict on the stack's pose, on status (its diagnostics go with the node's)."""
        self.status_pub.publish(String(data=json.dumps(check.as_dict())))

    def _publish_map(self, prepared: PreparedCloud, frame: str) -> None:
        """The map as the node uses it (downsampled, ground kept), latched for RViz."""
        self.map_pub.publish(xyz_to_cloud(prepared.map_view.surface,
                                          Header(stamp=self.get_clock().now().to_msg(), frame_id=frame)))


def main(args=None) -> int:
    profile = use_large_data_profile()
    rclpy.init(args=args)
    try:
        node = RegisterNode()
        if profile:
            node.get_logger().info(f"Fast DDS large-data transports: {profile} (set {profile_variable()} "
                                   "to use a profile of your own)")
    except (ConfigError, ParameterException) as exc:
        print(f"register_node: invalid parameter: {exc}", flush=True)
        rclpy.try_shutdown()
        return 1
    if node.localizer.settings.autostart:
        if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            print(f"register_node: {node.health.lifecycle}", flush=True)
            node.destroy_node()
            rclpy.try_shutdown()
            return 1
        node.trigger_activate()
    else:
        node.get_logger().info("waiting to be configured (autostart:=false): drive it with its lifecycle "
                               "services, as Nav2's lifecycle_manager does")
    executor = PoolExecutor(threads=2)
    try:
        spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # in this order: no callback or registration may use an entity destroy_node frees
        node.localizer.stop(STOP_WAIT_S)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
