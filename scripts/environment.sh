# Sourced by demo.sh and test.sh: set everything up for REGOR_ROS_DISTRO (default kilted), then
# enter its virtual environment and colcon install space, with DDS kept on this machine's loopback.
bash scripts/setup.sh
source scripts/distro.sh
set +u
# shellcheck disable=SC1090
source "$VENV/bin/activate" && source "$INSTALL/setup.bash"
set -u
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_LOCALHOST_ONLY=1
