#!/usr/bin/env bash
# Installs the built library into a temporary prefix and builds + runs a consumer project that
# uses find_package(specula). Usage: run.sh BUILD_DIR SOURCE_DIR
# The consumer is compiled with the build's own compiler flags (so an ASan/UBSan build links
# its sanitizer runtime too). Output of each step is shown only when it fails.
set -euo pipefail
build=$1; src=$2
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
cache_value() { sed -n "s/^$1:[A-Z]*=//p" "$build/CMakeCache.txt" | head -n1; }
cxx_flags=$(cache_value CMAKE_CXX_FLAGS)
link_flags=$(cache_value CMAKE_EXE_LINKER_FLAGS)
step() {
  local name=$1; shift
  if ! "$@" >"$tmp/$name.log" 2>&1; then
    echo "install test: step '$name' failed: $*" >&2
    cat "$tmp/$name.log" >&2
    exit 1
  fi
}
step install cmake --install "$build" --prefix "$tmp/prefix"
step configure cmake -S "$src/tests/install" -B "$tmp/consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$tmp/prefix" "-DCMAKE_CXX_FLAGS=$cxx_flags" "-DCMAKE_EXE_LINKER_FLAGS=$link_flags"
step build cmake --build "$tmp/consumer"
"$tmp/consumer/consumer"
