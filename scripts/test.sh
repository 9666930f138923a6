#!/usr/bin/env bash
# Quick start 2: install what is missing, build (warnings as errors) and run the whole suite.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cmake --preset ci >/dev/null
cmake --build --preset ci
ctest --preset ci
