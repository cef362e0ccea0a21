"""Start register_node with a preset parameter file and the two input topics remapped, with the
package's Fast DDS profile for large clouds (large_data:=false to keep the environment's own).

ros2 launch regor_ros register.launch.py preset:=outdoor source:=/velodyne_points target:=/map
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description():
    config_dir = os.path.join(get_package_share_directory("regor_ros"), "config")
    preset = LaunchConfiguration("preset")
    params_file = PythonExpression(["'", config_dir, "/' + '", preset, "' + '.yaml'"])
    return LaunchDescription([
        DeclareLaunchArgument("preset", default_value="indoor",
                              description="indoor, outdoor or object (config/<preset>.yaml)"),
        DeclareLaunchArgument("source", default_value="source_cloud",
                              description="PointCloud2 topic of the scan to localise"),
        DeclareLaunchArgument("target", default_value="target_cloud",
                              description="PointCloud2 topic of the scan or map to localise in"),
        DeclareLaunchArgument("mode", default_value="pairs", description="pairs or map"),
        DeclareLaunchArgument("rviz", default_value="false",
                              description="also start RViz with rviz/regor.rviz (clouds, aligned cloud, "
                                          "correspondences, pose; the target frame is the fixed frame)"),
        DeclareLaunchArgument("large_data", default_value="true",
                              description="use config/fastdds_large_data.xml (the driver should too)"),
        *[SetEnvironmentVariable(variable, os.path.join(config_dir, "fastdds_large_data.xml"),
                                 condition=IfCondition(LaunchConfiguration("large_data")))
          for variable in ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")],
        Node(
            package="regor_ros",
            executable="register_node",
            name="register_node",
            output="screen",
            parameters=[params_file, {"mode": LaunchConfiguration("mode")}],
            remappings=[("source_cloud", LaunchConfiguration("source")),
                        ("target_cloud", LaunchConfiguration("target"))],
        ),
        Node(
            package="rviz2",
            executable="rviz2",
            arguments=["-d", os.path.join(get_package_share_directory("regor_ros"), "rviz", "regor.rviz")],
            condition=IfCondition(LaunchConfiguration("rviz")),
        ),
    ])
