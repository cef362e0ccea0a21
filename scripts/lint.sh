#!/usr/bin/env bash
# Lint the package, its tests, launch files and lab scripts with ruff (ruff.toml); set up first like test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/environment.sh
ruff check regor_ros test launch lab
mypy   # the package's types (setup.cfg [mypy])
