#!/usr/bin/env bash
# CI stage 4: clang-tidy (clang-tidy-14) over specula's own sources with the checks of
# .clang-tidy, using the compile commands of the `ci` preset (configured here if needed; no
# build is required). Prints every finding; fails on a finding that is not in the baseline
# (scripts/tidy-baseline.txt: known findings per file and check, to be fixed by the owners of
# those files; a count may only go down). See docs/SECURITY.md, "Static analysis".
#
#   scripts/tidy.sh              src/ and apps/: the library and the CLI (what CI runs)
#   scripts/tidy.sh --all        also tests/ and bench/
#   scripts/tidy.sh --analyzer   also the clang static analyzer (core, C++, unix, security,
#                                dead code): about three times slower
#   scripts/tidy.sh [--all] [--analyzer] REGEX...   only the files whose path matches a REGEX
# Environment: SPECULA_JOBS (parallel clang-tidy processes, default: nproc).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
scope='src|apps'
extra_checks=''
files=()
for a in "$@"; do
  case $a in
    --all) scope='src|apps|tests|bench' ;;
    --analyzer) extra_checks=',clang-analyzer-core.*,clang-analyzer-cplusplus.*,clang-analyzer-unix.*,clang-analyzer-security.*,clang-analyzer-deadcode.*' ;;
    -h|--help) sed -n '2,13p' "$0"; exit 0 ;;
    -*) echo "tidy: unknown option '$a' (see scripts/tidy.sh --help)" >&2; exit 2 ;;
    *) files+=("$a") ;;
  esac
done
command -v run-clang-tidy-14 >/dev/null || scripts/setup.sh

[ -f build/ci/compile_commands.json ] || cmake --preset ci >/dev/null
regex="$root/($scope)/"
((${#files[@]})) && regex="$root/($scope)/.*($(IFS='|'; echo "${files[*]}"))"
checks=$(python3 -c 'import sys, re
text = open(".clang-tidy").read()
m = re.search(r"^Checks: >\n((?:  .*\n)+)", text, re.M)
print("".join(l.strip() for l in m.group(1).splitlines()))')

log=$(mktemp "${TMPDIR:-/tmp}/specula-tidy.XXXXXX")
trap 'rm -f "$log"' EXIT
t0=$SECONDS
n=$(python3 -c 'import json, re, sys
print(sum(1 for e in json.load(open("build/ci/compile_commands.json")) if re.search(sys.argv[1], e["file"])))' "$regex")
echo "tidy: $n files ($scope${files:+, matching ${files[*]}}), $(nproc) cores, ${SPECULA_JOBS:-$(nproc)} jobs${extra_checks:+, with the static analyzer}"
run-clang-tidy-14 -p build/ci -quiet -j "${SPECULA_JOBS:-$(nproc)}" -checks="$checks$extra_checks" "$regex" > "$log" 2>&1 || true

# Findings, once each (a header's finding is reported by every file that includes it), then
# compared per (file, check) with the baseline.
python3 - "$log" "$root" scripts/tidy-baseline.txt $((SECONDS - t0)) "$scope" "${#files[@]}" <<'EOF'
import collections, re, sys
log, root, baseline_path, secs = sys.argv[1], sys.argv[2] + "/", sys.argv[3], int(sys.argv[4])
# Folders whose files were all checked (headers of include/ come with src/): only for those can
# a lower count than the baseline's mean a fix.
checked = set(sys.argv[5].split("|")) | {"include"} if sys.argv[6] == "0" else set()
text = re.sub(r"\x1b\[[0-9;]*m", "", open(log, errors="replace").read())
pat = re.compile(r"^(/[^:\n]+):(\d+):(\d+): (warning|error): (.*?) \[([\w.,-]+)\]$", re.M)
findings = {}
for m in pat.finditer(text):
    path = m.group(1)
    path = path[len(root):] if path.startswith(root) else path
    findings.setdefault((path, int(m.group(2)), int(m.group(3)), m.group(6)), m.group(5))
# clang-tidy aborts a file it cannot parse: that is a failure too.
broken = sorted(set(re.findall(r"^Error while processing (\S+)", text, re.M)))
baseline = collections.Counter()
for line in open(baseline_path):
    line = line.split("#", 1)[0].split()
    if len(line) == 3:
        baseline[(line[0], line[1])] = int(line[2])
per = collections.Counter((f[0], f[3]) for f in findings)
new_keys = {k for k, c in per.items() if c > baseline.get(k, 0)}
new = 0
for (path, line, col, check), msg in sorted(findings.items()):
    known = (path, check) not in new_keys
    new += 0 if known else 1
    print(f"{'known' if known else 'NEW  '}  {path}:{line}:{col}: {msg} [{check}]")
gone = [(k, b, per.get(k, 0)) for k, b in sorted(baseline.items())
        if per.get(k, 0) < b and k[0].split("/", 1)[0] in checked]
for (path, check), b, now in gone:
    print(f"tidy: fixed: {path} {check}: {now} left of {b} in the baseline; lower it in {baseline_path}")
for b in broken:
    print(f"tidy: FAILED to process {b}")
print(f"tidy: {len(findings)} findings, {len(findings) - new} known (in {baseline_path}), {new} new; {secs} s")
if new or broken:
    print("tidy: FAILED: fix the new findings (or, for a false positive, add // NOLINT(check): reason)")
    sys.exit(1)
EOF
