#!/usr/bin/env bash
# Set up everything this repository needs on a fresh Debian machine without ROS: the Debian
# package libusb-1.0-0 (open3d), a virtual environment .venv with requirements.txt at the versions
# pinned in constraints.txt, and a colcon
# build of the package into build/ and install/. Safe to run again; it skips what is done.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then
  echo "== installing libusb-1.0-0 (needed by open3d)"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null || PYTHON=python3
if [ ! -x .venv/bin/python ]; then
  echo "== creating .venv with $PYTHON"
  "$PYTHON" -m venv .venv
fi
stamp=.venv/.requirements.sha
want=$(cat requirements.txt constraints.txt | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "== installing Python packages (requirements.txt, pinned by constraints.txt)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -r requirements.txt -c constraints.txt
  echo "$want" > "$stamp"
fi

echo "== colcon build"
# shellcheck disable=SC1091
source .venv/bin/activate
colcon --log-base build/colcon-log build --base-paths . --build-base build --install-base install \
  --event-handlers console_cohesion- summary- >/dev/null
# the command-line tools on the virtual environment's PATH as well (ros2 run finds them in lib/)
site=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
installed=$(ls -d "$PWD"/install/regor_ros/lib/python3*/site-packages)
echo "$installed" > "$site/regor_ros_install.pth"
for tool in regor-register regor-bench regor-calibrate-gate regor-pair-client; do
  ln -sf "$PWD/install/regor_ros/lib/regor_ros/$tool" ".venv/bin/$tool"
done
echo "== ready: source .venv/bin/activate && source install/setup.bash"
