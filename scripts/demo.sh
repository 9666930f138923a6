#!/usr/bin/env bash
# Quick start 1: install what is missing, build Release, render the default scene (pool).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cmake --preset release >/dev/null
cmake --build --preset release
mkdir -p out
build/release/specula render pool -o out/pool.png "$@"
