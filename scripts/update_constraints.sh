#!/usr/bin/env bash
# Re-resolve requirements/<distro>.txt to the newest versions in a scratch environment and write
# them to requirements/<distro>-constraints.txt (REGOR_ROS_DISTRO: kilted or jazzy); then run
# scripts/test.sh (which reinstalls the virtual environment from the new pins) and commit.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/distro.sh
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
"${PYTHON:-python3.11}" -m venv "$scratch/venv"
"$scratch/venv/bin/python" -m pip install -q --upgrade pip
"$scratch/venv/bin/python" -m pip install -q -r "$REQUIREMENTS"
{ head -2 "$CONSTRAINTS"; "$scratch/venv/bin/python" -m pip freeze | grep -v '^-e\|@ file'; } > "$CONSTRAINTS.new"
mv "$CONSTRAINTS.new" "$CONSTRAINTS"
echo "$CONSTRAINTS updated; now: REGOR_ROS_DISTRO=$REGOR_ROS_DISTRO bash scripts/test.sh"
