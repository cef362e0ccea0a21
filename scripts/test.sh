#!/usr/bin/env bash
# Set up, then run every test (core, message conversion, parameters, and the installed node
# over DDS on loopback) against one ROS 2 distribution: REGOR_ROS_DISTRO=kilted (default) or jazzy.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/environment.sh
echo "== tests on ROS 2 $REGOR_ROS_DISTRO (rclpy from $(python -c 'import rclpy, os; print(os.path.dirname(rclpy.__file__))'))"
exec python -m pytest -q -rs "${@:-test}"   # every test (-rs: each skipped one says why), or the arguments given
