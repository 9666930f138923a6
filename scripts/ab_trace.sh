#!/usr/bin/env bash
# A/B of two specula binaries' single-ray tracing speed per ray kind (bench trace), alternating.
#
#   scripts/ab_trace.sh [-c CPU] [-n ROUNDS] [-m MESH] OLD NEW
#
# Runs `taskset -c CPU BINARY bench trace --mesh MESH --threads 1 --repeat 7 --no-embree` for OLD,
# then NEW, ROUNDS times (default 6; MESH default ../shared/data/meshes/stanford-bunny.obj beside
# the checkout), and prints per binary and ray kind (primary, shadow, reflection, refraction,
# diffuse, random: the single-ray rows) the best and the median Mrays/s of the rounds.
# A single bench trace run swings 10-20% per kind on the shared VMs (BENCHMARKS.md); the best of
# several alternated rounds is what compares. Check that CPU is the quiet one first (ab.sh), and
# run both orders (OLD NEW, then NEW OLD): the binary run second in each round has been seen to
# gain 5-10% in every kind.
set -euo pipefail

cpu=0
rounds=6
mesh="$(cd "$(dirname "$0")/.." && pwd)/../shared/data/meshes/stanford-bunny.obj"
usage() { sed -n '2,/^[^#]/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit "${1:-2}"; }
while getopts "c:n:m:h" opt; do
  case "$opt" in
    c) cpu=$OPTARG ;;
    n) rounds=$OPTARG ;;
    m) mesh=$OPTARG ;;
    h) usage 0 ;;
    *) usage ;;
  esac
done
shift $((OPTIND - 1))
[[ $# -eq 2 ]] || usage
for b in "$@"; do
  [[ -x $b ]] || { echo "ab_trace.sh: $b is not an executable" >&2; exit 2; }
done
[[ -f $mesh ]] || { echo "ab_trace.sh: mesh $mesh not found (-m MESH)" >&2; exit 2; }

results=$(mktemp)
trap 'rm -f "$results"' EXIT
for ((r = 1; r <= rounds; r++)); do
  for b in "$@"; do
    taskset -c "$cpu" "$b" bench trace --mesh "$mesh" --threads 1 --repeat 7 --no-embree 2>&1 |
      awk -v bin="$b" '/^(primary|shadow|reflection|refraction|diffuse|random) / && !seen[$1]++ { print bin, $1, $5 }' \
        >>"$results"
  done
done
# Per binary and kind: best and median (sorted numerically, middle element).
for b in "$@"; do
  line="$b:"
  for k in primary shadow reflection refraction diffuse random; do
    vals=$(awk -v bin="$b" -v kind="$k" '$1 == bin && $2 == kind { print $3 }' "$results" | sort -g)
    n=$(wc -l <<<"$vals")
    best=$(tail -1 <<<"$vals")
    med=$(sed -n "$(((n + 1) / 2))p" <<<"$vals")
    line+=" ${k:0:4} $best/$med"
  done
  echo "$line"
done
echo "(Mrays/s, best/median of $rounds rounds, CPU $cpu, one thread)"
