"""Relocalize in a saved map: register_node in map mode with the map and its trajectory from
files, scans from the robot's driver, odometry to fuse them, poses for Nav2. Not tested here
(launch_ros is not on the package index); the same node and parameters are, through the
installed executable.

ros2 launch regor_ros relocalize.launch.py map_file:=/maps/site.pcd map_trajectory_file:=/maps/site_tum.txt \\
    scan:=/velodyne_points odometry:=/odom base_to_sensor:="'0.3, 0, 1.2, 0, 0, 0'"
Then: ros2 service call /register_node/relocalize std_srvs/srv/Trigger
With autostart:=false the node waits for a lifecycle manager (Nav2's lifecycle_manager).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription

ARGUMENTS = [  # name, default, description
    ("params_file", os.path.join(get_package_share_directory("regor_ros"), "config", "outdoor.yaml"),
     "parameter file (config/<preset>.yaml or your own)"),
    ("map_file", "", "the map (.pcd, .ply, .npy, .xyz/.txt, KITTI .bin)"),
    ("map_trajectory_file", "", "the sensor poses the map was built from (TUM); '' = none"),
    ("map_frame", "map", "frame of the map's points, and of the poses published"),
    ("scan", "/points", "PointCloud2 topic of the robot's scans"),
    ("odometry", "/odom", "nav_msgs/Odometry topic: scans are fused along it (accumulate_scans)"),
    ("registration", "on_demand", "on_demand (after a relocalize call) or continuous"),
    ("base_frame", "base_link", "publish the pose of this frame (the robot's base)"),
    ("base_to_sensor", "0, 0, 0, 0, 0, 0", "the sensor's mounting on the base: 'x, y, z, roll, pitch, yaw'"),
    ("autostart", "true", "configure and activate at start; false: a lifecycle manager drives it"),
]


def generate_launch_description():
    profile = os.path.join(get_package_share_directory("regor_ros"), "config", "fastdds_large_data.xml")
    value = LaunchConfiguration
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in ARGUMENTS],
        SetEnvironmentVariable("FASTDDS_DEFAULT_PROFILES_FILE", profile),
        Node(
            package="regor_ros",
            executable="register_node",
            name="register_node",
            output="screen",
            parameters=[value("params_file"), {
                "mode": "map", "autostart": ParameterValue(value("autostart"), value_type=bool),
                **{name: ParameterValue(value(name), value_type=str) for name in (
                    "map_file", "map_trajectory_file", "map_frame", "registration", "base_frame", "base_to_sensor")}}],
            # pose_with_covariance goes to Nav2 as /initialpose; initial_guess is not wired to it
            # (the node ignores its own poses anyway)
            remappings=[("source_cloud", value("scan")), ("odometry", value("odometry")),
                        ("pose_with_covariance", "/initialpose")],
        ),
    ])
