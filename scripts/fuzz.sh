#!/usr/bin/env bash
# CI stage 3: builds the `fuzz` preset (clang-14, libFuzzer + ASan + UBSan) and runs every fuzz
# target for SECONDS_PER_TARGET (default 60) from a scratch copy of its seed corpus
# (fuzz/corpus/<target>, plus small extracts of the shipped meshes from ../shared/data/meshes
# when present), with its dictionary. Prints each target's report (executions, coverage,
# exec/s) and fails if any target found a crash, leak, timeout or out-of-memory input; those
# inputs are copied to tests/data/fuzz-regressions/<target>/, where the normal test suite
# replays them (tests/fuzz_regression_test.cpp). See docs/SECURITY.md.
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]     e.g. scripts/fuzz.sh 3600 fuzz_ply
# Environment: SPECULA_JOBS (build jobs, default: nproc), SPECULA_FUZZ_KEEP=1 keeps the scratch
# folder (grown corpora, logs) and prints its path.
#
# Reproducible: every target runs as one process with libFuzzer's -seed=SPECULA_FUZZ_SEED
# (default 1; 0 = a random seed, which the report prints), -reload=0 (no time-driven corpus
# re-reads) and, where the kernel allows it, address-space randomisation off (setarch -R: heap
# addresses feed libFuzzer's comparison tracing), so the sequence of inputs it tries depends only
# on the seed, the seed corpus and the code: a finding at execution K comes back in any run that
# gets that far. SPECULA_FUZZ_RUNS=N also stops each target after N executions (-runs=N), which
# makes the whole run, its coverage figures included, repeat exactly.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
secs=${1:-60}
shift || true
[[ "$secs" =~ ^[0-9]+$ ]] || { echo "usage: scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]" >&2; exit 2; }
seed=${SPECULA_FUZZ_SEED:-1}
runs=${SPECULA_FUZZ_RUNS:-}
[[ "$seed" =~ ^[0-9]+$ ]] && ((seed < 4294967296)) ||
  { echo "fuzz: SPECULA_FUZZ_SEED must be a number from 0 (random) to 4294967295" >&2; exit 2; }
[[ -z "$runs" || "$runs" =~ ^[1-9][0-9]*$ ]] || { echo "fuzz: SPECULA_FUZZ_RUNS must be a positive number" >&2; exit 2; }

scripts/setup.sh
cmake --preset fuzz >/dev/null
cmake --build --preset fuzz --parallel "${SPECULA_JOBS:-$(nproc)}"

bin=build/fuzz/fuzz
if (($#)); then targets=("$@"); else mapfile -t targets < "$bin/targets.txt"; fi

scratch=$(mktemp -d "${TMPDIR:-/tmp}/specula-fuzz-run.XXXXXX")
if [ "${SPECULA_FUZZ_KEEP:-0}" = 1 ]; then
  echo "fuzz: scratch folder kept: $scratch"
else
  trap 'rm -rf "$scratch"' EXIT
fi

# Small valid extracts of the shipped meshes: the first 300 v / vt / vn lines and the faces that
# use only those (the whole files are 0.2-2.4 MB, too slow to mutate).
meshes=${SPECULA_DATA:-$root/../shared/data/meshes}
obj_extracts() {
  local out=$1 f
  [ -d "$meshes" ] || return 0
  for f in "$meshes"/*.obj; do
    [ -f "$f" ] || continue
    awk -v N=300 '
      function ok(tok,   parts, n, i) { n = split(tok, parts, "/")
        for (i = 1; i <= n; i++) if (parts[i] != "" && (parts[i] + 0 > N || parts[i] + 0 < 0)) return 0
        return 1 }
      $1 == "v" { if (++nv <= N) print; next }
      $1 == "vt" { if (++nt <= N) print; next }
      $1 == "vn" { if (++nn <= N) print; next }
      $1 == "f" { for (i = 2; i <= NF; i++) if (!ok($i)) next; if (++nf <= 2 * N) print; next }
      { if (++other <= 50) print }' "$f" > "$out/shipped_$(basename "$f")"
  done
}

dict_of() {
  case $1 in
    fuzz_glb|fuzz_gltf) echo fuzz/dict/gltf.dict ;;
    *) echo "fuzz/dict/${1#fuzz_}.dict" ;;
  esac
}

# Address-space randomisation off for the fuzzers, when the kernel lets us (see the top).
norand=()
setarch -R true 2>/dev/null && norand=(setarch -R)

failed=()
found=0
printf '\nfuzz: %s s%s per target, seed %s%s: %s\n' "$secs" "${runs:+ or $runs executions}" \
  "$([ "$seed" = 0 ] && echo "random (SPECULA_FUZZ_SEED=0)" || echo "$seed")" \
  "$( ((${#norand[@]})) && echo ", ASLR off" || echo ", ASLR on (setarch -R refused: runs may drift)")" "${targets[*]}"
for t in "${targets[@]}"; do
  [ -x "$bin/$t" ] || { echo "fuzz: no such target '$t' (see $bin/targets.txt)" >&2; exit 2; }
  work=$scratch/$t
  mkdir -p "$work/corpus" "$work/artifacts" "$work/tmp"
  cp -r "fuzz/corpus/$t/." "$work/corpus/"
  [ "$t" = fuzz_obj ] && obj_extracts "$work/corpus"
  seeds=$(find "$work/corpus" -type f | wc -l)
  args=("$work/corpus" -seed="$seed" -reload=0 -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048
        -max_len=65536 -artifact_prefix="$work/artifacts/" -print_final_stats=1)
  [ -n "$runs" ] && args+=(-runs="$runs")
  dict=$(dict_of "$t")
  [ -f "$dict" ] && args+=(-dict="$dict")
  rc=0
  # The target's private file folder goes under TMPDIR: libFuzzer leaves with _Exit, which skips
  # the target's clean-up, so it is put in the scratch folder that is removed here.
  TMPDIR="$work/tmp" "${norand[@]}" "$bin/$t" "${args[@]}" > "$work/log" 2>&1 || rc=$?
  # Report: libFuzzer's last status line and its final statistics.
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/log" | tail -1)
  speed=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$work/log" | tail -1)
  rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "$work/log" | tail -1)
  status=$(grep -E '^#[0-9]+' "$work/log" | tail -1 || true)
  cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<< "$status")
  ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<< "$status")
  corp=$(sed -n 's/.* corp: \([0-9]*\).*/\1/p' <<< "$status")
  used_seed=$(sed -n 's/^INFO: Seed: \([0-9]*\).*/\1/p' "$work/log" | head -1)
  crashes=$(find "$work/artifacts" -type f \( -name 'crash-*' -o -name 'leak-*' -o -name 'timeout-*' -o -name 'oom-*' \) | sort)
  printf 'fuzz: %-16s seed %-10s %10s execs  %6s exec/s  cov %6s  ft %6s  corpus %4s -> %-4s  rss %5s MB  %s\n' \
    "$t" "${used_seed:-?}" "${execs:-?}" "${speed:-?}" "${cov:-?}" "${ft:-?}" "$seeds" "${corp:-?}" "${rss:-?}" \
    "$([ -z "$crashes" ] && [ $rc -eq 0 ] && echo ok || echo FAILED)"
  if [ -n "$crashes" ] || [ $rc -ne 0 ]; then
    failed+=("$t")
    dest=tests/data/fuzz-regressions/$t
    mkdir -p "$dest"
    while IFS= read -r c; do
      [ -n "$c" ] || continue
      cp "$c" "$dest/"
      found=$((found + 1))
      echo "fuzz: $t: saved $dest/$(basename "$c")"
    done <<< "$crashes"
    echo "fuzz: $t: to repeat this run: SPECULA_FUZZ_SEED=${used_seed:-$seed} SPECULA_FUZZ_RUNS=${execs:-N} scripts/fuzz.sh $secs $t"
    echo "---- $t: end of the log ($work/log)"
    grep -v -E '^#[0-9]+' "$work/log" | tail -n 60
    echo "----"
  fi
done

if ((${#failed[@]})); then
  echo "fuzz: FAILED: ${failed[*]} ($found input(s) saved under tests/data/fuzz-regressions/;" \
       "fix the bug, keep the file: tests/fuzz_regression_test.cpp replays it)" >&2
  exit 1
fi
echo "fuzz: all ${#targets[@]} targets ran ${secs} s each without a crash"
