# Sourced by the other scripts: where the chosen ROS 2 distribution's environment lives.
# REGOR_ROS_DISTRO=kilted (default) or jazzy.
REGOR_ROS_DISTRO="${REGOR_ROS_DISTRO:-kilted}"
case "$REGOR_ROS_DISTRO" in
  kilted) VENV=.venv; BUILD=build; INSTALL=install ;;
  jazzy) VENV=.venv-jazzy; BUILD=build-jazzy; INSTALL=install-jazzy ;;
  *) echo "REGOR_ROS_DISTRO=$REGOR_ROS_DISTRO: choose kilted or jazzy" >&2; exit 2 ;;
esac
REQUIREMENTS="requirements/$REGOR_ROS_DISTRO.txt"
CONSTRAINTS="requirements/$REGOR_ROS_DISTRO-constraints.txt"
export REGOR_ROS_DISTRO
