#!/usr/bin/env bash
# Re-resolve requirements.txt to the newest versions in a scratch environment and write them to
# constraints.txt; then run scripts/test.sh (which reinstalls .venv from the new pins) and commit.
set -euo pipefail
cd "$(dirname "$0")/.."
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
"${PYTHON:-python3.11}" -m venv "$scratch/venv"
"$scratch/venv/bin/python" -m pip install -q --upgrade pip
"$scratch/venv/bin/python" -m pip install -q -r requirements.txt
{ head -2 constraints.txt; "$scratch/venv/bin/python" -m pip freeze | grep -v '^-e\|@ file'; } > constraints.new
mv constraints.new constraints.txt
echo "constraints.txt updated; now: bash scripts/test.sh"
