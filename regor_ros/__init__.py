"""regor_ros: global point cloud registration (Regor, CVPR 2025) for ROS 2."""
