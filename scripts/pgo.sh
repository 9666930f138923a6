#!/usr/bin/env bash
# Builds build/pgo/specula with profile-guided optimisation (GCC): an instrumented build, a
# training run, then the optimised build from its profile. About twice a release build's time
# plus ~30 s of training on 2 cores.
#
#   scripts/pgo.sh            then: build/pgo/specula render pool --camera water ...
#
# The training covers what the library runs hot, broadly rather than one benchmark view:
#   - Whitted renders of every built-in scene (pool's four cameras with and without shadow rays,
#     cornell, glassbox, a small city) through the BVH, the octree (cubes and contours) and the
#     grid, and of an .svo file the voxelizer wrote;
#   - the voxelizer (the bunny at depths 6 and 8, or the pool scene without the shared data);
#   - `bench trace` with every BVH traversal kernel this CPU runs (builds, single rays, packets).
# Code it does not reach (other CPUs' kernels and clones) is optimised as without a profile.
# Images and .svo files are the same bit for bit as the plain release build's (BENCHMARKS.md).
# Environment: SPECULA_JOBS (build jobs, default: nproc).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
jobs=${SPECULA_JOBS:-$(nproc)}
build=$root/build/pgo
profile=$build/pgo-profile

scripts/setup.sh
command -v g++ >/dev/null || { echo "pgo: GCC (g++) is needed for profile-guided builds" >&2; exit 2; }

echo "==== pgo: 1/3 instrumented build ($build)"
rm -rf "$profile"
cmake --preset pgo -DSPECULA_PGO=generate -DSPECULA_PGO_DIR="$profile" >/dev/null
cmake --build --preset pgo --parallel "$jobs"

echo "==== pgo: 2/3 training"
bin=$build/specula
work=$(mktemp -d "${TMPDIR:-/tmp}/specula-pgo.XXXXXX")
trap 'rm -rf "$work"' EXIT
t0=$SECONDS
run() {
  printf '  %s\n' "$*"
  "$bin" "$@" >"$work/log" 2>&1 || { cat "$work/log" >&2; echo "pgo: training step failed: specula $*" >&2; exit 1; }
}
img=(--width 320 --height 240 --frames 1)
for cam in overview water bunny parallel; do
  run render pool --camera "$cam" "${img[@]}" -o "$work/a.png"
  run render pool --camera "$cam" "${img[@]}" --no-shadows -o "$work/a.png"
done
for mode in cubes contours; do
  for cam in water bunny parallel; do
    run render pool --accel svo --depth 7 --voxel-mode "$mode" --camera "$cam" "${img[@]}" --no-shadows -o "$work/a.png"
  done
done
run render pool --accel svo --depth 6 --camera water "${img[@]}" -o "$work/a.png"
run render pool --accel grid --depth 7 --camera water "${img[@]}" -o "$work/a.png"
run render cornell "${img[@]}" -o "$work/a.png"
run render glassbox "${img[@]}" -o "$work/a.png"
run render city:150000 --width 320 --height 180 --frames 1 -o "$work/a.png"
mesh=../shared/data/meshes/stanford-bunny.obj
if [[ -f $mesh ]]; then
  vox=$mesh
  trace=(--mesh "$mesh")
else
  echo "  (no $mesh: training the voxelizer and bench trace on the pool scene instead)"
  vox=pool
  trace=(--scene pool)
fi
run voxelize "$vox" --depth 8 --repeat 3
run voxelize "$vox" --depth 6 -o "$work/b.svo"
run render "$work/b.svo" "${img[@]}" -o "$work/a.png"
for kernel in sse4 avx2x8 avx512x8 avx512x16; do
  args=(bench trace "${trace[@]}" --bvh-kernel "$kernel" --width 320 --height 240 --repeat 2 --no-embree)
  printf '  %s\n' "${args[*]}"
  if ! "$bin" "${args[@]}" >"$work/log" 2>&1; then
    # A kernel this CPU cannot run is refused up front (bvh_build.cpp); any other failure stops.
    grep -q "needs a CPU feature this machine lacks" "$work/log" ||
      { cat "$work/log" >&2; echo "pgo: training step failed: specula ${args[*]}" >&2; exit 1; }
    echo "  (kernel $kernel: not on this CPU)"
  fi
done
echo "  training took $((SECONDS - t0)) s; profile: $profile"

echo "==== pgo: 3/3 optimised build"
cmake --preset pgo -DSPECULA_PGO=use -DSPECULA_PGO_DIR="$profile" >/dev/null
cmake --build --preset pgo --parallel "$jobs"
echo "==== pgo: done: $bin"
