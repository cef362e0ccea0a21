#!/usr/bin/env bash
# Set up, then run every test (core, message conversion, parameters, and the installed node
# over DDS on loopback).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/environment.sh
exec python -m pytest -q test "$@"
