# Sourced by demo.sh and test.sh: set everything up, then enter the virtual environment and the
# colcon install space, with DDS kept on this machine's loopback.
bash scripts/setup.sh
set +u
# shellcheck disable=SC1091
source .venv/bin/activate && source install/setup.bash
set -u
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_LOCALHOST_ONLY=1
