"""register_node: Regor registration of two PointCloud2 topics, published as a pose.

A lifecycle node, as Nav2 manages them: configure loads the map file (or fails with the reason),
activate starts registering and publishing, deactivate stops, cleanup releases the map and every
entity; with ``autostart`` (the default) it configures and activates itself. The node is the ROS
side: its lifecycle, parameters, services and diagnostics here, what it listens to
(subscriptions.py) and what it publishes (outputs.py); the work (inputs, map, the worker thread) is
ros/localizer.py's, so the executor keeps answering parameters and services while it registers.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.srv import LoadMap
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from std_srvs.srv import Trigger

from ..core import ConfigError, RegistrationError
from .diagnostics import diagnostic_array, seconds_since_process_start
from .localizer import Localizer
from .outputs import Outputs
from .parameters import apply_changes, declare_parameters, unknown_overrides, unused_settings
from .subscriptions import Subscriptions

STOP_WAIT_S = 0.3  # how long a stop waits for the worker (a registration or map preparation under way is abandoned)


class RegisterNode(LifecycleNode):
    def __init__(self):
        super().__init__("register_node")
        config, settings = declare_parameters(self)
        for warning in unknown_overrides(self) + unused_settings(config, settings):
            self.get_logger().warning(warning)
        self.outputs = Outputs(self, lambda: self.localizer.shared.settings)
        up = self.outputs.while_up
        self.localizer = Localizer(config, settings, self.get_logger(), up(self.outputs.outcome),
                                   up(self.outputs.map), up(self.outputs.check))
        self.inputs = Subscriptions(self, self.localizer, self.outputs)
        self.health = self.localizer.report.health   # the one Health of the node's life, the localizer's to update
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._service_entities = []
        # /diagnostics from the start: a node waiting for its lifecycle manager, or whose
        # configure failed, says so
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        if settings.diagnostics_period > 0:
            self.create_timer(settings.diagnostics_period, self._publish_diagnostics)

    # --- lifecycle ---

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """The kernels and the map file (Localizer.configure: a map that cannot be used fails with
        the reason), then the inputs, outputs and services."""
        try:
            kernels_s = self.localizer.configure()
        except RegistrationError as exc:
            self.health.lifecycle = f"configure failed: map_file not usable: {exc}"
            self.get_logger().error(self.health.lifecycle)
            return TransitionCallbackReturn.FAILURE
        config, settings = self.localizer.shared.snapshot()
        self.inputs.make(settings)
        # their own callback groups: a call waits for a registration or a map while scans keep arriving
        self._service_entities = [self.create_service(Trigger, "~/relocalize", self._on_relocalize,
                                              callback_group=MutuallyExclusiveCallbackGroup()),
                          self.create_service(LoadMap, "~/load_map", self._on_load_map,
                                              callback_group=MutuallyExclusiveCallbackGroup())]
        self.outputs.make()
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

    def _destroy_entities(self) -> None:
        self.outputs.destroy()
        for service in reversed(self._service_entities):
            self.destroy_service(service)
        self._service_entities = []
        self.inputs.destroy()

    # --- parameters and diagnostics ---

    def _on_set_parameters(self, params) -> SetParametersResult:
        try:
            self.localizer.change(lambda config, settings: apply_changes(
                config, settings, {p.name: p.value for p in params}))
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _publish_diagnostics(self) -> None:
        with self.localizer.lock:
            array = diagnostic_array(self.health, self.get_fully_qualified_name(),
                                     self.get_clock().now().to_msg())
        self.diagnostics_pub.publish(array)

    # --- services ---

    def _on_relocalize(self, request, response):
        """Answer with the registration of the next source: its verdict and the reason."""
        answer = self.localizer.relocalize()
        response.success, response.message = answer.accepted, answer.text
        return response

    def _on_load_map(self, request, response):
        """Swap the map for another file (MapSlot.use_url); the old one stays until it is ready or if it fails."""
        if self.localizer.shared.settings.mode != "map":
            response.result = LoadMap.Response.RESULT_UNDEFINED_FAILURE
            self.get_logger().error("load_map: the node is in pairs mode (mode:=map loads maps)")
            return response
        try:
            self.localizer.maps.use_url(request.map_url)
            response.result = LoadMap.Response.RESULT_SUCCESS
        except FileNotFoundError as exc:
            response.result = LoadMap.Response.RESULT_MAP_DOES_NOT_EXIST
            self.get_logger().error(f"load_map: no such file, the previous map stays: {exc}")
        except RegistrationError as exc:
            response.result = LoadMap.Response.RESULT_INVALID_MAP_DATA
            self.get_logger().error(f"load_map: map not usable, the previous one stays: {exc}")
        return response
