#!/usr/bin/env bash
# Set up everything this repository needs on a fresh Debian machine without ROS, for one ROS 2
# distribution (REGOR_ROS_DISTRO: kilted, the default, or jazzy): the Debian package libusb-1.0-0
# (open3d), a virtual environment with requirements/<distro>.txt at the versions pinned in
# requirements/<distro>-constraints.txt, and a colcon build of the package. Kilted uses .venv,
# build/ and install/; another distribution .venv-<distro>, build-<distro>/, install-<distro>/.
# Safe to run again; it skips what is done.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/distro.sh

if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then
  echo "== installing libusb-1.0-0 (needed by open3d)"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null || PYTHON=python3
if [ ! -x "$VENV/bin/python" ]; then
  echo "== creating $VENV with $PYTHON ($REGOR_ROS_DISTRO)"
  "$PYTHON" -m venv "$VENV"
fi
stamp="$VENV/.requirements.sha"
want=$(cat requirements/common.txt "$REQUIREMENTS" "$CONSTRAINTS" | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "== installing Python packages ($REQUIREMENTS, pinned by $CONSTRAINTS)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -r "$REQUIREMENTS" -c "$CONSTRAINTS"
  echo "$want" > "$stamp"
fi

echo "== colcon build ($REGOR_ROS_DISTRO)"
# shellcheck disable=SC1091
source "$VENV/bin/activate"
colcon --log-base "$BUILD/colcon-log" build --base-paths . --build-base "$BUILD" --install-base "$INSTALL" \
  --event-handlers console_cohesion- summary- >/dev/null
# the command-line tools on the virtual environment's PATH as well (ros2 run finds them in lib/)
site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
ls -d "$PWD/$INSTALL"/regor_ros/lib/python3*/site-packages > "$site/regor_ros_install.pth"
for tool in regor-register regor-batch regor-bench regor-calibrate-gate regor-pair-client regor-relocalize regor-verify regor-replay; do
  ln -sf "$PWD/$INSTALL/regor_ros/lib/regor_ros/$tool" "$VENV/bin/$tool"
done
# the build compiled the installed package's kernels (setup.py's install step); the source tree's
# are compiled here, for the tests that import it
echo "== compiling the registration kernels of the source tree (numba's disk cache)"
"$PWD/$VENV/bin/python" -c "from regor_ros.core import warm_up; warm_up()"
echo "== ready: source $VENV/bin/activate && source $INSTALL/setup.bash"
