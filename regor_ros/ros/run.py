"""register_node's process: rclpy up, the node configured and activated (autostart, or left to a
lifecycle manager), spun until shutdown, and taken down in an order that leaves no callback or
registration using what destroy_node frees."""
from __future__ import annotations

import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import TransitionCallbackReturn

from ..core import ConfigError
from .node import STOP_WAIT_S, RegisterNode
from .spin import PoolExecutor, spin
from .transport import profile_variable, use_large_data_profile

HELP_FLAGS = ("-h", "--help")


USAGE = """usage: register_node [--ros-args [-p NAME:=VALUE]... [--params-file FILE] [-r FROM:=TO]...]

Global point cloud registration for ROS 2 (Regor): the pose of source_cloud in target_cloud (pairs)
or in a map (mode:=map), with no initial guess. Parameter files per preset are installed in
share/regor_ros/config (indoor.yaml, outdoor.yaml, object.yaml); doc/node.md is the reference.

examples:
  register_node --ros-args --params-file <prefix>/share/regor_ros/config/outdoor.yaml \\
      -r source_cloud:=/points -r target_cloud:=/map_cloud
  register_node --ros-args -p preset:=outdoor -p mode:=map -p map_file:=/maps/site.pcd \\
      -p map_trajectory_file:=/maps/site_tum.txt -r source_cloud:=/points -r odometry:=/odom

parameters (NAME default; the core's are the indoor preset's defaults):
"""


def usage() -> str:
    """The --help text: how to start it, and every parameter with its default."""
    from dataclasses import fields

    from ..core import RegorConfig
    from .parameters import PRESET_FIELD, NodeSettings
    rows = [("preset", PRESET_FIELD.default)] + [(f.name, f.default) for f in fields(NodeSettings)]
    rows += [(name, default) for name, default, _ in RegorConfig.preset("indoor").parameters()]
    return USAGE + "\n".join(f"  {name} {default!r}" for name, default in rows)


def main(args=None) -> int:
    argv = sys.argv if args is None else list(args)
    ros_part = argv[argv.index("--ros-args"):] if "--ros-args" in argv else []
    if any(a in HELP_FLAGS for a in argv[1:]):
        if any(a in HELP_FLAGS for a in ros_part):
            print("register_node: --help goes before --ros-args (ROS arguments take no --help)", file=sys.stderr)
        print(usage())
        return 0
    profile = use_large_data_profile()
    try:
        rclpy.init(args=args)
    except Exception as exc:   # rcl's UnknownROSArgsError and the like: a malformed command line
        print(f"register_node: the ROS arguments cannot be used: {exc} (register_node --help)", file=sys.stderr)
        return 2
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
