#!/usr/bin/env bash
# Installs the Debian 12 packages specula needs (only the missing ones). Safe to re-run.
set -euo pipefail
PKGS=(build-essential cmake ninja-build pkg-config
      libtbb-dev libtinyobjloader-dev libtinygltf-dev libstb-dev libtinyexr-dev
      nlohmann-json3-dev libcli11-dev libgtest-dev libgmock-dev libbenchmark-dev
      libembree-dev assimp-testmodels
      clang-14 libclang-rt-14-dev zlib1g-dev   # fuzz preset: clang + libFuzzer runtime; zlib for tinyexr
      clang-tidy-14)                           # scripts/tidy.sh
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}" >&2
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
