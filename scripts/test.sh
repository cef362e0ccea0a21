#!/usr/bin/env bash
# Set up, then run every test (core, message conversion, parameters, and the installed node
# over DDS on loopback).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
set +u
# shellcheck disable=SC1091
source .venv/bin/activate && source install/setup.bash
set -u
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_LOCALHOST_ONLY=1
exec python -m pytest -q test "$@"
