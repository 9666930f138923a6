#!/usr/bin/env bash
# A/B timing of two specula binaries on one pinned CPU, alternating old and new.
#
#   scripts/ab.sh [-c CPU] [-n ROUNDS] [-g REGEX] OLD NEW -- ARGS...
#
# Runs `taskset -c CPU OLD ARGS`, then NEW, ROUNDS times (default 4), keeps from each run's
# output the first line matching REGEX (default '^(render|total) ': the frame time of `render`,
# the voxelize + octree time of `voxelize`), reads its first "N ms" figure, and
# prints every round, then the lowest and the median figure per binary.
#
# Why pinned and single-threaded: on the shared 2-vCPU VMs one vCPU is at times ~35% slower
# than the other for minutes (its host core is busy; BENCHMARKS.md, 2026-12-04 evening). A
# 2-thread run then swings 10-20% and hides a 1-3% change; one thread pinned to a quiet vCPU
# repeats within ~0.3%. A phase change shows as a 20-40% jump of one run (both binaries were
# the same file when this was seen): rerun then. Check first that the chosen CPU is the fast
# one, e.g.
#   for c in 0 1; do taskset -c $c build/release/specula render pool --camera water \
#     --no-shadows --threads 1 --frames 15 | grep ^render; done
# and pass --threads 1 in ARGS.
set -euo pipefail

cpu=0
rounds=4
regex='^(render|total) '
usage() { sed -n '2,/^[^#]/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit "${1:-2}"; }
while getopts "c:n:g:h" opt; do
  case "$opt" in
    c) cpu=$OPTARG ;;
    n) rounds=$OPTARG ;;
    g) regex=$OPTARG ;;
    h) usage 0 ;;
    *) usage ;;
  esac
done
shift $((OPTIND - 1))
[[ $# -ge 3 && $3 == "--" ]] || usage
old=$1 new=$2
shift 3
for b in "$old" "$new"; do
  [[ -x $b ]] || { echo "ab.sh: $b is not an executable" >&2; exit 2; }
done
[[ $rounds =~ ^[1-9][0-9]*$ ]] || { echo "ab.sh: -n needs a positive whole number" >&2; exit 2; }
command -v taskset >/dev/null || { echo "ab.sh: taskset is missing (apt install util-linux)" >&2; exit 2; }

declare -a t_old t_new
for ((r = 1; r <= rounds; ++r)); do
  for which in old new; do
    bin=$old
    [[ $which == new ]] && bin=$new
    line=$(taskset -c "$cpu" "$bin" "$@" 2>&1 | grep -E -m1 -- "$regex" || true)
    [[ -n $line ]] || { echo "ab.sh: no line matching '$regex' from $bin $*" >&2; exit 1; }
    ms=$(grep -E -o '[0-9]+(\.[0-9]+)? ms' <<<"$line" | head -1 | cut -d' ' -f1 || true)
    [[ -n $ms ]] || { echo "ab.sh: no \"N ms\" figure in: $line" >&2; exit 1; }
    printf '%-4s %s\n' "$which" "$line"
    if [[ $which == old ]]; then t_old+=("$ms"); else t_new+=("$ms"); fi
  done
done
summary() {
  printf '%s\n' "${@:2}" | sort -g | awk -v name="$1" '
    { v[NR] = $1 } END { if (NR == 0) exit; m = (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2;
      printf "%-4s lowest %.2f ms, median %.2f ms (%d runs)\n", name, v[1], m, NR }'
}
if [[ -n ${t_old[*]:-} ]]; then summary old "${t_old[@]}"; fi
if [[ -n ${t_new[*]:-} ]]; then summary new "${t_new[@]}"; fi
