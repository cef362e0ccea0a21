# Sourced by demo.sh and test.sh: set everything up for REGOR_ROS_DISTRO (default kilted), then
# enter its virtual environment and colcon install space, with DDS kept on this machine's loopback
# and Fast DDS configured for large clouds (config/fastdds_large_data.xml) in every process.
bash scripts/setup.sh
source scripts/distro.sh
set +u
# shellcheck disable=SC1090
source "$VENV/bin/activate" && source "$INSTALL/setup.bash"
set -u
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_LOCALHOST_ONLY=1
export "$PROFILES_VARIABLE=$PWD/config/fastdds_large_data.xml"
