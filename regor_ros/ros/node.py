"""register_node: Regor registration of two PointCloud2 topics, published as a pose.

A lifecycle node, as Nav2 manages them: configure reads the parameters and loads the map file (a
map that cannot be loaded fails configure with the reason), activate starts registering and
publishing, deactivate stops, cleanup releases the map and every entity. With ``autostart`` (the
default) it configures and activates itself, so ``ros2 run`` works alone.

Callbacks only store the newest messages (ros/inputs.py decides what is stale and what the worker
does next); one worker thread prepares maps and registers, so the executor keeps answering
parameter changes and service calls.
"""
from __future__ import annotations

import dataclasses
import re
import threading
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
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, PointCloud2
from std_msgs.msg import Header, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from ..core import (
    ConfigError,
    PreparedCloud,
    RegistrationError,
    ScanHistory,
    attached_pose,
    prepare_cloud,
    register,
    transform_points,
    warm_up,
)
from ..io.map_file import load_map_file
from .diagnostics import Health, diagnostic_array, seconds_since_process_start
from .imu_up import ImuUp
from .initial_guess import region_of_guess
from .input_qos import InputSubscription, fixed_profile
from .inputs import Cloud, InputBuffer, Job, PrepareMap, Register
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

WARN_THROTTLE_S = 5.0
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
    def __init__(self):
        super().__init__("register_node")
        self.config, self.settings = declare_parameters(self)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._lock = threading.Condition()
        self.stats = {"source_clouds": 0, "target_clouds": 0, "odometry_messages": 0, "registrations": 0,
                      "accepted_poses": 0,
                      "dropped_stale": 0, "bad_inputs": 0, "map_preparations": 0}
        self.health = Health(counters=self.stats, map_from_file=bool(self.settings.map_file))
        self._entities = []      # (destroy, entity) of what configure created, for cleanup
        self._worker: threading.Thread | None = None
        self._active = False
        self._stopping = False
        self._own_poses = deque(maxlen=OWN_POSES_KEPT)  # (stamp, position) of poses published
        self._reset()
        # /diagnostics from the start: a node waiting for its lifecycle manager, or whose
        # configure failed, says so
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if self.settings.diagnostics_period > 0:
            self.create_timer(self.settings.diagnostics_period, self._publish_diagnostics)

    def _reset(self) -> None:
        """The inputs, the map and the answers of one configured lifetime."""
        self._inputs = InputBuffer()
        self._prepared_target: PreparedCloud | None = None
        self._prepared_key = None  # what the prepared map was made from (_map_key)
        self._map_frame = ""       # and the frame it is in
        self._guess: PoseWithCovarianceStamped | None = None  # in force until a pose is accepted
        self._answer = (0, False, "")  # (source serial, accepted, what happened) of the last registration
        self._history = ScanHistory(self._history_capacity())  # scans and odometry, for accumulation
        self._warned = {}  # kind of bad input -> when it was last logged

    # --- lifecycle ---

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Compile the registration kernels (or load them from numba's disk cache) so the first
        relocalization does not pay it, load the map file (or fail with the reason), then create
        the inputs, outputs and the worker."""
        start = time.perf_counter()
        warm_up()
        kernels_s = time.perf_counter() - start
        self.get_logger().info(f"registration kernels ready in {kernels_s:.2f} s")
        with self._lock:
            config, settings = self.config, self.settings
            self._reset()
            self._stopping = False
        if settings.map_file:
            try:
                self._use_map_file(settings.map_file, settings.map_trajectory_file, config, settings)
            except RegistrationError as exc:
                self.health.lifecycle = f"configure failed: map_file not usable: {exc}"
                self.get_logger().error(self.health.lifecycle)
                return TransitionCallbackReturn.FAILURE
        self._create_entities(settings)
        self._worker = threading.Thread(target=self._work, name="regor_worker", daemon=True)
        self._worker.start()
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
        with self._lock:
            self._active = True
            prepared, frame = self._prepared_target, self._map_frame
            self._lock.notify_all()
        self.health.lifecycle = "active"
        if self.settings.map_file and prepared is not None:
            self._publish_map(prepared, frame)
        self.get_logger().info("active: registering")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        with self._lock:
            self._active = False
        self.health.lifecycle = "inactive"
        self.get_logger().info("inactive: not registering (activate resumes; the map stays loaded)")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.stop(STOP_WAIT_S)
        self._destroy_entities()
        with self._lock:
            self._reset()
        self.health.lifecycle = "unconfigured"
        self.health.map_info = {}
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.stop(STOP_WAIT_S)
        self._destroy_entities()
        self.health.lifecycle = "finalized"
        return TransitionCallbackReturn.SUCCESS

    def _create_entities(self, settings) -> None:
        def keep(destroy, entity):
            self._entities.append((destroy, entity))
            return entity

        self.inputs = {"source": InputSubscription(self, PointCloud2, "source_cloud", self._on_source,
                                                   settings.source_qos)}
        if not settings.map_file:  # else the map is a file
            self.inputs["target"] = InputSubscription(self, PointCloud2, "target_cloud", self._on_target,
                                                      settings.target_qos)
        for subscription in self.inputs.values():
            keep(lambda s: s.destroy(), subscription)
        self._follow_publishers()
        keep(self.destroy_timer, self.create_timer(QOS_CHECK_PERIOD_S, self._follow_publishers))
        keep(self.destroy_subscription, self.create_subscription(
            PoseWithCovarianceStamped, "initial_guess", self._on_initial_guess, fixed_profile("reliable")))
        # best effort accepts reliable and best-effort publishers alike; a deep queue for 100 Hz odometry
        keep(self.destroy_subscription, self.create_subscription(
            Odometry, "odometry", self._on_odometry,
            QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)))
        self._imu = ImuUp() if settings.imu_topic else None  # the source's up, for the gravity prior
        if self._imu is not None:
            keep(self.destroy_subscription, self.create_subscription(
                Imu, settings.imu_topic, self._on_imu,
                QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)))
        # their own callback groups: a call waits for a registration or a map while scans keep arriving
        keep(self.destroy_service, self.create_service(Trigger, "~/relocalize", self._on_relocalize,
                                                       callback_group=MutuallyExclusiveCallbackGroup()))
        keep(self.destroy_service, self.create_service(LoadMap, "~/load_map", self._on_load_map,
                                                       callback_group=MutuallyExclusiveCallbackGroup()))
        publish = [("pose_pub", PoseStamped, "pose", 10),
                   ("pose_cov_pub", PoseWithCovarianceStamped, "pose_with_covariance", 10),
                   ("marker_pub", MarkerArray, "correspondences", 10), ("candidates_pub", PoseArray, "candidates", 10),
                   ("status_pub", String, "status", 10), ("aligned_pub", PointCloud2, "aligned_cloud", 1),
                   ("map_pub", PointCloud2, "map_cloud", fixed_profile("transient_local"))]
        for attribute, msg_type, topic, qos in publish:
            setattr(self, attribute, keep(self.destroy_lifecycle_publisher,
                                          self.create_lifecycle_publisher(msg_type, topic, qos)))

    def _destroy_entities(self) -> None:
        for destroy, entity in reversed(self._entities):
            destroy(entity)
        self._entities = []

    # --- parameters ---

    def _on_set_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        try:
            with self._lock:
                self.config, self.settings = apply_changes(self.config, self.settings, changes)
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _follow_publishers(self) -> None:
        for which, subscription in self.inputs.items():
            subscription.update()
            self.health.inputs[f"{which}_qos"] = subscription.state()

    def _publish_diagnostics(self) -> None:
        with self._lock:
            array = diagnostic_array(self.health, self.get_fully_qualified_name(),
                                     self.get_clock().now().to_msg())
        self.diagnostics_pub.publish(array)

    # --- inputs: convert, keep only the newest ---

    def _on_source(self, msg: PointCloud2) -> None:
        self._store("source", msg)

    def _on_target(self, msg: PointCloud2) -> None:
        self._store("target", msg)

    def _history_capacity(self) -> int:
        """Scans kept for accumulation: twice the scans fused, so ones without odometry can be skipped."""
        return 2 * self.settings.accumulation().scans + 2

    def _on_odometry(self, msg: Odometry) -> None:
        """The scan frame's pose in the odometry frame at the message's stamp."""
        pose = matrix_from_pose(msg.pose.pose) @ self.settings.odometry_extrinsic()
        with self._lock:
            self.stats["odometry_messages"] += 1
            self._history.add_odometry(_stamp_seconds(msg.header), pose)

    def _on_imu(self, msg: Imu) -> None:
        """REP 145: an orientation_covariance[0] of -1 says no orientation is reported."""
        q, a = msg.orientation, msg.linear_acceleration
        orientation = None if msg.orientation_covariance[0] == -1.0 else np.array([q.x, q.y, q.z, q.w])
        with self._lock:
            self._imu.add(_stamp_seconds(msg.header), orientation, np.array([a.x, a.y, a.z]))

    def _gravity(self, config, settings, src: Cloud):
        """The configuration with the source's up direction from the IMU at the scan's stamp (or
        unknown when the IMU gave none: no prior rather than a stale one), and what it was."""
        if self._imu is None:
            return config, {"direction": config.gravity.source_up, "from": "gravity.source_up"}
        with self._lock:
            up, where = self._imu.up_at(src.stamp, settings.imu_window,
                                        settings.imu_extrinsic()[:3, :3])
        text = "unknown" if up is None else " ".join(f"{v:.6f}" for v in up)
        return config.replace({"gravity.source_up": text}), {"direction": text, "from": where}

    def _on_initial_guess(self, msg: PoseWithCovarianceStamped) -> None:
        """A hint, unless it is one of this node's own poses come back (pose_with_covariance
        remapped to /initialpose while initial_guess listens there: it would narrow the search
        to wherever the last pose was, right or wrong)."""
        if _pose_key(msg) in self._own_poses:
            return
        with self._lock:
            self._guess = msg
            self._lock.notify_all()
        self.get_logger().info(
            f"initial guess received: ({msg.pose.pose.position.x:.1f}, {msg.pose.pose.position.y:.1f}, "
            f"{msg.pose.pose.position.z:.1f}) in '{msg.header.frame_id}'; in force until a pose is accepted")

    def _on_relocalize(self, request, response):
        """Answer with the registration of the next source: its verdict and the reason."""
        if not self._active:
            response.success = False
            response.message = f"not registering: the node is {self.health.lifecycle} (activate it)"
            return response
        with self._lock:
            after = self._inputs.serials["source"]
            self._inputs.relocalize_after = after
            self._lock.notify_all()
            answered = self._lock.wait_for(lambda: self._answer[0] > after or self._stopping,
                                           self.settings.relocalize_timeout)
            self._inputs.relocalize_after = None
            _, response.success, response.message = self._answer
        if not answered:
            response.success = False
            waiting = ("no map yet" if self.settings.mode == "map" and self._prepared_target is None
                       else "no source cloud arrived")
            response.message = f"{waiting} within relocalize_timeout={self.settings.relocalize_timeout:g} s"
        return response

    def _store(self, which: str, msg: PointCloud2) -> None:
        if not self._active:  # inactive: inputs are not taken (a lifecycle node's contract)
            return
        try:
            points = cloud_to_xyz(msg)
        except RegistrationError as exc:
            self._bad_input(f"{which}_cloud skipped: {exc}")
            return
        stamp = _stamp_seconds(msg.header)
        with self._lock:
            self.stats[f"{which}_clouds"] += 1
            self.stats["dropped_stale"] += self._inputs.store(which, msg.header, stamp, points, self.settings.mode)
            if which == "source":
                self._history.add_scan(stamp, points, self._history_capacity())
            self._lock.notify_all()

    def _bad_input(self, text: str) -> None:
        """Count and warn, at most once per WARN_THROTTLE_S for each kind of problem (the text
        with its numbers blanked), so a flood of one bad kind cannot hide another."""
        kind = re.sub(r"[-+.\de]*\d[-+.\de]*", "#", text)
        now = time.monotonic()
        with self._lock:
            self.stats["bad_inputs"] += 1
            self.health.last_bad_input = text
            if now - self._warned.get(kind, -WARN_THROTTLE_S) < WARN_THROTTLE_S:
                return
            self._warned[kind] = now
        self.get_logger().warning(text)

    # --- the worker ---

    def _next_job(self) -> Job | None:
        if not self._active:
            return None
        return self._inputs.next_job(self.settings, self.config.features, self._prepared_key,
                                     self._prepared_target is not None)

    def _work(self) -> None:
        while True:
            with self._lock:
                job = self._next_job()
                while job is None and not self._stopping:
                    self._lock.wait(0.5)
                    job = self._next_job()
                if self._stopping:
                    return
                config, settings, guess = self.config, self.settings, self._guess
                if isinstance(job, Register):
                    self._inputs.taken(job)
            if isinstance(job, PrepareMap):
                self._prepare_map(job.key, job.target, config, settings)
            else:
                accepted, what = self._register(job.source, job.target, config, settings, guess)
                with self._lock:
                    self._answer = (job.source.serial, accepted, what)
                    self._lock.notify_all()

    def _prepare_map(self, key, tgt: Cloud | None, config, settings) -> None:
        """Prepare the map once per message or file (and feature settings); queries wait meanwhile."""
        try:
            if settings.map_file:
                self._use_map_file(key[1], key[2], config, settings)
            else:
                self._use_map(lambda: (prepare_cloud(tgt.points, config, "target", viewpoint=key[2]), {}),
                              key, tgt.header.frame_id)
        except RegistrationError as exc:
            with self._lock:
                if not self._stopping:
                    self._prepared_target, self._prepared_key, self._map_frame = None, key, ""
            self.health.last_error = f"map not usable: {exc}"
            self._bad_input(f"map skipped: {exc}")

    def _use_map_file(self, map_file: str, trajectory_file: str, config, settings) -> None:
        """Load (or prepare and cache) a map file and use it; raises RegistrationError with the reason."""
        key = ("file", map_file, trajectory_file, config.features)

        def load():
            loaded = load_map_file(map_file, config, trajectory_file or None, settings.map_cache,
                                   settings.map_cache_dir, warn=self.get_logger().warning)
            return loaded.prepared, loaded.info

        prepared = self._use_map(load, key, settings.map_frame)
        if prepared is not None and self._active:  # for RViz: the map as the node uses it
            self._publish_map(prepared, settings.map_frame)

    def _use_map(self, prepare, key, frame: str) -> PreparedCloud | None:
        """Run ``prepare`` (-> prepared map, info) and make its map the one registered against;
        the old map stays in use until then. None when the node stopped meanwhile."""
        self.health.preparing_map = True
        start = time.perf_counter()
        try:
            prepared, info = prepare()
        finally:
            self.health.preparing_map = False
        seconds = time.perf_counter() - start
        with self._lock:
            if self._stopping:  # the node's publishers are going away
                return None
            self._prepared_target, self._prepared_key, self._map_frame = prepared, key, frame
            self.stats["map_preparations"] += 1
            self.health.last_error = ""
            self.health.map_info = {
                "map_points": prepared.input_size, "map_keypoints": len(prepared),
                "map_exact_search": prepared.index.exact, **info,
                "map_preparation_seconds": round(seconds, 3)}
            self._lock.notify_all()
        cache = f", cache {info['map_cache']}" if info.get("map_cache") else ""
        self.get_logger().info(f"map prepared: {prepared.input_size} points, {len(prepared)} keypoints "
                               f"in {seconds:.1f} s{cache}")
        return prepared

    def _publish_map(self, prepared: PreparedCloud, frame: str) -> None:
        """The map as the node uses it (downsampled, ground kept), latched for RViz."""
        self.map_pub.publish(xyz_to_cloud(prepared.map_view.surface,
                                          Header(stamp=self.get_clock().now().to_msg(), frame_id=frame)))

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
        with self._lock:
            config, settings = self.config, self.settings
        try:
            self._use_map_file(path, trajectory, config, settings)
        except RegistrationError as exc:
            response.result = LoadMap.Response.RESULT_INVALID_MAP_DATA
            self.get_logger().error(f"load_map: map not usable, the previous one stays: {exc}")
            return response
        with self._lock:
            self.settings = dataclasses.replace(self.settings, map_file=path, map_trajectory_file=trajectory)
        self.health.map_from_file = True
        response.result = LoadMap.Response.RESULT_SUCCESS
        return response

    def _guess_region(self, guess: PoseWithCovarianceStamped | None, target_frame: str, settings):
        """The initial guess as a search region, or None; a guess in another frame is dropped with a warning."""
        if guess is None:
            return None
        if guess.header.frame_id and guess.header.frame_id != target_frame:
            with self._lock:
                if self._guess is guess:
                    self._guess = None
            self._bad_input(f"initial_guess dropped: it is in '{guess.header.frame_id}', the target "
                            f"cloud in '{target_frame}' (this node does not look up tf)")
            return None
        return region_of_guess(guess, settings.initial_guess_sigmas, settings.initial_guess_min_radius,
                             settings.initial_guess_max_radius)

    def _source_input(self, src: Cloud, settings):
        """The scan alone, or fused with the scans before it along odometry (accumulate_scans), and
        what was fused (for status)."""
        limits = settings.accumulation()
        if limits.scans < 2:
            return src.points, None
        with self._lock:
            sequence, info = self._history.sequence(src.stamp, limits,
                                                    settings.viewpoints()[0])
        return (src.points if sequence is None else sequence), info

    def _register(self, src: Cloud, tgt: Cloud | None, config, settings, guess) -> tuple[bool, str]:
        """Register the source against the pair's target or (map mode) the prepared map; (pose
        accepted, what happened)."""
        source_viewpoint, target_viewpoint = settings.viewpoints()
        if settings.mode == "map":
            with self._lock:
                target, target_frame = self._prepared_target, self._map_frame
        else:
            target, target_frame = tgt.points, tgt.header.frame_id
        try:
            config, source_up = self._gravity(config, settings, src)
            region = self._guess_region(guess, target_frame, settings)
            source, accumulation = self._source_input(src, settings)
            if source is src.points:
                result = register(source, target, config, source_viewpoint=source_viewpoint,
                                  target_viewpoint=target_viewpoint, search_region=region)
            else:  # the fused scans carry their viewpoints (the scan frame's origin)
                result = register(source, target, config, target_viewpoint=target_viewpoint,
                                  search_region=region)
        except RegistrationError as exc:
            self.health.last_error = str(exc)
            self._bad_input(f"registration skipped: {exc}")
            return False, f"registration skipped: {exc}"
        except Exception as exc:  # keep the node alive whatever the input did
            self.health.last_error = f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"registration failed: {type(exc).__name__}: {exc}")
            return False, f"registration failed: {type(exc).__name__}: {exc}"
        with self._lock:
            if self._stopping:  # the node's publishers are going away
                return False, "node stopping"
            self.stats["registrations"] += 1
            self.stats["accepted_poses"] += int(result.accepted)
            self.health.last_error = self.health.last_bad_input = ""
            self.health.last_summary = result.summary()
            if result.accepted and region is not None and self._guess is guess:
                self._guess = None  # the robot is found: the guess has done its job
            extra = {"source_stamp": src.stamp, "source_frame": src.header.frame_id,
                     "target_frame": target_frame,
                     "pose_of": settings.base_frame or src.header.frame_id,
                     "mode": settings.mode, **self.stats, **self.health.inputs, "accumulation": accumulation,
                     "source_up": source_up, "target_up": config.gravity.target_up,
                     **(self.health.map_info if settings.mode == "map" else {}),
                     "search_region": None if region is None else {
                         "centre": [float(v) for v in region.centre], "radius": region.radius}}
        header = Header(stamp=src.header.stamp, frame_id=target_frame)
        self.status_pub.publish(status_message(result, extra))
        self.marker_pub.publish(correspondence_markers(result, header, settings.max_markers,
                                                       settings.marker_line_width))
        base = np.linalg.inv(settings.base_extrinsic()) if settings.base_frame else None
        self.candidates_pub.publish(candidate_poses(result, header, settings.max_candidates, base))
        figures = (f"{result.num_inliers} inliers, fitness {result.fitness:.2f}, "
                   f"{result.timings['total']:.2f} s")
        if not result.accepted:
            self.get_logger().warning(f"pose rejected: {result.reason} ({figures})")
            if not settings.publish_rejected:
                return False, f"pose withheld: {result.reason}"
        else:
            self.get_logger().info(f"pose accepted: {figures}")
        T, covariance = result.transform, result.covariance
        if base is not None:  # the robot's pose, for Nav2: the sensor's composed with its mounting
            T, covariance = attached_pose(T, covariance, base)
        self.pose_pub.publish(pose_stamped(T, header))
        own = pose_with_covariance(T, covariance, header)
        self._own_poses.append(_pose_key(own))
        self.pose_cov_pub.publish(own)
        if settings.publish_aligned_cloud:
            self.aligned_pub.publish(xyz_to_cloud(transform_points(result.transform, src.points), header))
        return result.accepted, (f"pose published ({figures})" if result.accepted
                                 else f"pose published although rejected: {result.reason}")

    def stop(self, timeout: float) -> None:
        """Stop the worker: wait up to timeout for it to finish (a registration or map preparation
        under way is abandoned; it publishes nothing once stopping) and wake a waiting relocalize call."""
        with self._lock:
            self._stopping = True
            self._active = False
            self._lock.notify_all()
        if self._worker is not None:
            self._worker.join(timeout)
            self._worker = None


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
        node.stop(STOP_WAIT_S)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
