#!/usr/bin/env bash
# CI stage 2: the whole CTest suite built with AddressSanitizer + UndefinedBehaviorSanitizer
# (the `asan` preset: any memory error, leak or undefined behaviour fails the test that hit it).
# Environment: SPECULA_JOBS (build jobs, default: nproc).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cmake --preset asan >/dev/null
cmake --build --preset asan --parallel "${SPECULA_JOBS:-$(nproc)}"
ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1} \
UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1} \
  ctest --preset asan
