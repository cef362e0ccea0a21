"""register_node: Regor registration of two PointCloud2 topics, published as a pose.

A lifecycle node, as Nav2 manages them: configure reads the parameters and loads the map file (a
map that cannot be loaded fails configure with the reason), activate starts registering and
publishing, deactivate stops, cleanup releases the map and every entity. With ``autostart`` (the
default) it configures and activates itself, so ``ros2 run`` works alone.

The node is the ROS side: the lifecycle, the parameters, the entities and the translation between
messages and the core's arrays. The work (the inputs, the map, the worker thread that prepares maps
and registers) is ros/localizer.py's, so the executor keeps answering parameter changes and service
calls while a registration runs.
"""
from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from urllib.parse import parse_qs, urlparse

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from nav_msgs.srv import LoadMap
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, LifecycleState, TransitionCallbackReturn
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, PointCloud2
from std_msgs.msg import Header, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from ..core import ConfigError, PreparedCloud, RegistrationError, attached_pose, transform_points, warm_up
from .diagnostics import diagnostic_array, seconds_since_process_start
from .initial_guess import region_of_guess
from .input_qos import InputSubscription, fixed_profile
from .localizer import Hint, Localizer, Outcome
from .messages import (
    candidate_poses,
    correspondence_markers,
    matrix_from_pose,
    pose_stamped,
    pose_with_covariance,
    status_message,
)
from .parameters import apply_changes, declare_parameters
from .pointcloud import cloud_to_xyz, xyz_to_cloud
from .transport import use_large_data_profile

STOP_WAIT_S = 0.3  # how long a stop waits for the worker (a registration or map preparation under way is abandoned)
QOS_CHECK_PERIOD_S = 0.5  # how often auto QoS inputs look at their publishers
OWN_POSES_KEPT = 20  # poses published, remembered so that one coming back as a hint is recognised


def _stamp_seconds(header: Header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def _pose_key(msg: PoseWithCovarianceStamped) -> tuple:
    p = msg.pose.pose.position
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id,
            round(p.x, 6), round(p.y, 6), round(p.z, 6))


class RegisterNode(LifecycleNode):
    # created in configure, destroyed in cleanup
    pose_pub: LifecyclePublisher
    pose_cov_pub: LifecyclePublisher
    marker_pub: LifecyclePublisher
    candidates_pub: LifecyclePublisher
    status_pub: LifecyclePublisher
    aligned_pub: LifecyclePublisher
    map_pub: LifecyclePublisher

    def __init__(self):
        super().__init__("register_node")
        config, settings = declare_parameters(self)
        self.localizer = Localizer(config, settings, self.get_logger(), self._publish_outcome, self._publish_map)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._entities = []      # (destroy, entity) of what configure created, for cleanup
        self.inputs: dict[str, InputSubscription] = {}
        self._own_poses = deque(maxlen=OWN_POSES_KEPT)  # (stamp, position) of poses published
        # /diagnostics from the start: a node waiting for its lifecycle manager, or whose
        # configure failed, says so
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if settings.diagnostics_period > 0:
            self.create_timer(settings.diagnostics_period, self._publish_diagnostics)

    @property
    def settings(self):
        return self.localizer.settings

    @property
    def health(self):
        return self.localizer.health

    # --- lifecycle ---

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Compile the registration kernels (or load them from numba's disk cache) so the first
        relocalization does not pay it, load the map file (or fail with the reason), then create
        the inputs, outputs and the worker."""
        start = time.perf_counter()
        warm_up()
        kernels_s = time.perf_counter() - start
        self.get_logger().info(f"registration kernels ready in {kernels_s:.2f} s")
        with self.localizer.lock:
            config, settings = self.localizer.config, self.localizer.settings
        try:
            self.localizer.configure(config, settings)
        except RegistrationError as exc:
            self.health.lifecycle = f"configure failed: map_file not usable: {exc}"
            self.get_logger().error(self.health.lifecycle)
            return TransitionCallbackReturn.FAILURE
        self._create_entities(settings)
        self.localizer.start()
        self.health.lifecycle = "inactive"
        self.health.ready_after_s = seconds_since_process_start()
        map_s = self.health.map_info.get("map_preparation_seconds")
        self.get_logger().info(
            f"configured: mode={settings.mode}, voxel={config.features.voxel_size} m; "
            f"listening on {self.resolve_topic_name('source_cloud')}; the target from "
            f"{settings.map_file or self.resolve_topic_name('target_cloud')}")
        self.get_logger().info(
            "ready to register" + (f" {self.health.ready_after_s:.1f} s after the process started" if
                                   self.health.ready_after_s is not None else "")
            + f" (kernels {kernels_s:.2f} s" + (f", map {map_s:.1f} s)" if map_s is not None else ")"))
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        super().on_activate(state)  # the lifecycle publishers
        self.localizer.set_active(True)
        self.health.lifecycle = "active"
        with self.localizer.lock:
            prepared, frame = self.localizer.map, self.localizer.map_frame
        if self.settings.map_file and prepared is not None:
            self._publish_map(prepared, frame)
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
        with self.localizer.lock:
            self.localizer.reset()
        self.health.lifecycle = "unconfigured"
        self.health.map_info = {}
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

        self.inputs = {"source": InputSubscription(self, PointCloud2, "source_cloud", self._on_source,
                                                   settings.source_qos)}
        if not settings.map_file:  # else the map is a file
            self.inputs["target"] = InputSubscription(self, PointCloud2, "target_cloud", self._on_target,
                                                      settings.target_qos)
        for input_subscription in self.inputs.values():
            keep(lambda s: s.destroy(), input_subscription)
        self._follow_publishers()
        keep(self.destroy_timer, self.create_timer(QOS_CHECK_PERIOD_S, self._follow_publishers))
        subscription(PoseWithCovarianceStamped, "initial_guess", self._on_initial_guess, fixed_profile("reliable"))
        # best effort accepts reliable and best-effort publishers alike; a deep queue for 100 Hz odometry
        subscription(Odometry, "odometry", self._on_odometry,
                     QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
        if settings.imu_topic:  # the source's up, for the gravity prior
            subscription(Imu, settings.imu_topic, self._on_imu,
                         QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200,
                                    reliability=ReliabilityPolicy.BEST_EFFORT))
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
        changes = {p.name: p.value for p in params}
        try:
            with self.localizer.lock:
                localizer = self.localizer
                localizer.config, localizer.settings = apply_changes(localizer.config, localizer.settings, changes)
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

    def _on_source(self, msg: PointCloud2) -> None:
        self._store("source", msg)

    def _on_target(self, msg: PointCloud2) -> None:
        self._store("target", msg)

    def _store(self, which: str, msg: PointCloud2) -> None:
        if not self.localizer.active:  # inactive: inputs are not taken (a lifecycle node's contract)
            return
        try:
            points = cloud_to_xyz(msg)
        except RegistrationError as exc:
            self.localizer.bad_input(f"{which}_cloud skipped: {exc}")
            return
        self.localizer.store(which, msg.header, _stamp_seconds(msg.header), points)

    def _on_odometry(self, msg: Odometry) -> None:
        """The scan frame's pose in the odometry frame at the message's stamp."""
        pose = matrix_from_pose(msg.pose.pose) @ self.settings.odometry_extrinsic()
        self.localizer.add_odometry(_stamp_seconds(msg.header), pose)

    def _on_imu(self, msg: Imu) -> None:
        """REP 145: an orientation_covariance[0] of -1 says no orientation is reported."""
        q, a = msg.orientation, msg.linear_acceleration
        orientation = None if msg.orientation_covariance[0] == -1.0 else np.array([q.x, q.y, q.z, q.w])
        self.localizer.add_imu(_stamp_seconds(msg.header), orientation, np.array([a.x, a.y, a.z]))

    def _on_initial_guess(self, msg: PoseWithCovarianceStamped) -> None:
        """A hint, unless it is one of this node's own poses come back (pose_with_covariance
        remapped to /initialpose while initial_guess listens there: it would narrow the search
        to wherever the last pose was, right or wrong)."""
        if _pose_key(msg) in self._own_poses:
            return
        settings = self.settings
        self.localizer.set_hint(Hint(msg.header.frame_id, region_of_guess(
            msg, settings.initial_guess_sigmas, settings.initial_guess_min_radius,
            settings.initial_guess_max_radius)))
        self.get_logger().info(
            f"initial guess received: ({msg.pose.pose.position.x:.1f}, {msg.pose.pose.position.y:.1f}, "
            f"{msg.pose.pose.position.z:.1f}) in '{msg.header.frame_id}'; in force until a pose is accepted")

    # --- services ---

    def _on_relocalize(self, request, response):
        """Answer with the registration of the next source: its verdict and the reason."""
        if not self.localizer.active:
            response.success = False
            response.message = f"not registering: the node is {self.health.lifecycle} (activate it)"
            return response
        response.success, response.message = self.localizer.relocalize(self.settings.relocalize_timeout)
        return response

    def _on_load_map(self, request, response):
        """Swap the map for another file (nav_msgs/LoadMap: ``map_url`` is the map's path or
        file:// URL, with ``?trajectory=PATH`` for its TUM trajectory). The cache is used as at
        start; the old map stays until the new one is ready, and stays when it fails."""
        if self.settings.mode != "map":
            response.result = LoadMap.Response.RESULT_UNDEFINED_FAILURE
            self.get_logger().error("load_map: the node is in pairs mode (mode:=map loads maps)")
            return response
        url = urlparse(request.map_url)
        path = url.path if url.scheme in ("", "file") else ""
        trajectory = parse_qs(url.query).get("trajectory", [""])[0]
        missing = [p for p in (path, trajectory) if p and not Path(p).expanduser().is_file()]
        if not path or missing:
            response.result = LoadMap.Response.RESULT_MAP_DOES_NOT_EXIST
            self.get_logger().error(f"load_map: no such file, the previous map stays: "
                                    f"{missing[0] if missing else request.map_url!r}")
            return response
        try:
            self.localizer.use_map_file(path, trajectory)
        except RegistrationError as exc:
            response.result = LoadMap.Response.RESULT_INVALID_MAP_DATA
            self.get_logger().error(f"load_map: map not usable, the previous one stays: {exc}")
            return response
        response.result = LoadMap.Response.RESULT_SUCCESS
        return response

    # --- outputs ---

    def _publish_outcome(self, outcome: Outcome) -> None:
        """A registration's status, correspondences and candidates, and its pose when it goes out."""
        result, settings = outcome.result, self.settings
        header = Header(stamp=outcome.source.header.stamp, frame_id=outcome.target_frame)
        self.status_pub.publish(status_message(result, outcome.status))
        self.marker_pub.publish(correspondence_markers(result, header, settings.max_markers,
                                                       settings.marker_line_width))
        base = np.linalg.inv(settings.base_extrinsic()) if settings.base_frame else None
        self.candidates_pub.publish(candidate_poses(result, header, settings.max_candidates, base))
        if not outcome.publish:
            return
        T, covariance = result.transform, result.covariance
        if base is not None:  # the robot's pose, for Nav2: the sensor's composed with its mounting
            T, covariance = attached_pose(T, covariance, base)
        self.pose_pub.publish(pose_stamped(T, header))
        own = pose_with_covariance(T, covariance, header)
        self._own_poses.append(_pose_key(own))
        self.pose_cov_pub.publish(own)
        if settings.publish_aligned_cloud:
            self.aligned_pub.publish(xyz_to_cloud(transform_points(result.transform, outcome.source.points),
                                                  header))

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
            node.get_logger().info(f"Fast DDS large-data transports: {profile} (set FASTDDS_DEFAULT_PROFILES_FILE "
                                   "to use your own)")
    except (ConfigError, ParameterException) as exc:
        print(f"register_node: invalid parameter: {exc}", flush=True)
        rclpy.try_shutdown()
        return 1
    if node.settings.autostart:
        if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            print(f"register_node: {node.health.lifecycle}", flush=True)
            node.destroy_node()
            rclpy.try_shutdown()
            return 1
        node.trigger_activate()
    else:
        node.get_logger().info("waiting to be configured (autostart:=false): drive it with its lifecycle "
                               "services, as Nav2's lifecycle_manager does")
    executor = MultiThreadedExecutor(num_threads=2)
    try:
        rclpy.spin(node, executor)
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
