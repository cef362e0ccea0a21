"""register_node's process: rclpy up, the node configured and activated (autostart, or left to a
lifecycle manager), spun until shutdown, and taken down in an order that leaves no callback or
registration using what destroy_node frees."""
from __future__ import annotations

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import TransitionCallbackReturn

from ..core import ConfigError
from .node import STOP_WAIT_S, RegisterNode
from .spin import PoolExecutor, spin
from .transport import profile_variable, use_large_data_profile


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
    if node.localizer.shared.settings.autostart:
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
