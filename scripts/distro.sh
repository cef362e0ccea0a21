# Sourced by the other scripts: where the chosen ROS 2 distribution's environment lives.
# REGOR_ROS_DISTRO=kilted (default) or jazzy.
REGOR_ROS_DISTRO="${REGOR_ROS_DISTRO:-kilted}"
case "$REGOR_ROS_DISTRO" in
  kilted) VENV=.venv; BUILD=build; INSTALL=install; PROFILES_VARIABLE=FASTDDS_DEFAULT_PROFILES_FILE ;;
  jazzy) VENV=.venv-jazzy; BUILD=build-jazzy; INSTALL=install-jazzy; PROFILES_VARIABLE=FASTRTPS_DEFAULT_PROFILES_FILE ;;
  *) echo "REGOR_ROS_DISTRO=$REGOR_ROS_DISTRO: choose kilted or jazzy" >&2; exit 2 ;;
esac
REQUIREMENTS="requirements/$REGOR_ROS_DISTRO.txt"
CONSTRAINTS="requirements/$REGOR_ROS_DISTRO-constraints.txt"
export REGOR_ROS_DISTRO
