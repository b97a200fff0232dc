#!/usr/bin/env bash
# The Slurm executor of `visloc map build` against the local one (issue #12):
# a one-node cluster (scripts/slurm-local.sh) on this machine, a small
# synthetic street built with --executor local and with --executor slurm; the
# maps must have the same segments, images and points per segment. Then one
# segment is removed from the Slurm map and a second run must resubmit that
# segment alone. Skips (exit 77) without slurm-wlm, munge or COLMAP.
#   map_build_slurm_test.sh VISLOC REPO_ROOT
set -euo pipefail
V="$(realpath "$1")"; ROOT="$(realpath "$2")"
for p in slurmctld slurmd munged mungekey sbatch squeue scontrol sinfo colmap; do
  command -v "$p" >/dev/null 2>&1 || { echo "SKIP: $p is not installed (slurm-wlm, munge, colmap)"; exit 77; }
done
W="$(mktemp -d /tmp/visloc-slurm-test.XXXXXX)"
export SLURM_LOCAL_BASE="$W/slurm" SLURM_LOCAL_PORT="${VISLOC_TEST_SLURM_PORT:-6917}"
cleanup() { "$ROOT/scripts/slurm-local.sh" stop >/dev/null 2>&1 || true; rm -rf "$W"; }
trap cleanup EXIT
"$ROOT/scripts/slurm-local.sh" start || { echo "SKIP: the one-node Slurm cluster did not start here (see above)"; exit 77; }
export SLURM_CONF="$W/slurm/etc/slurm.conf"

"$V" synth city --out "$W/city" --road-length 60 --headings 8 --elevations 10 --size 400x400 --queries 1 --jobs 2 --quiet
common=(--images "$W/city/images" --gps "$W/city/gps.csv" --poses known --known-poses "$W/city/sparse"
        --min-placemarks 3 --max-placemarks 4 --overlap 1 --pq-training-images 8)
"$V" map build "${common[@]}" --out "$W/local" --jobs 2 --no-retrieval > "$W/local.txt"
"$V" map build "${common[@]}" --out "$W/slurm" --executor slurm > "$W/slurm.txt"
cat "$W/slurm.txt"

summary() {  # id images points per segment, from map info --json
  "$V" map info "$1" --json | /usr/bin/python3 -c '
import json, sys
for s in json.load(sys.stdin)["segments"]:
    print(s["id"], s["images"], s["points"])'
}
summary "$W/local" > "$W/local.sum"
summary "$W/slurm" > "$W/slurm.sum"
echo "local:"; cat "$W/local.sum"; echo "slurm:"; cat "$W/slurm.sum"
[ "$(wc -l < "$W/local.sum")" -ge 2 ] || { echo "FAIL: expected at least 2 segments"; exit 1; }
diff "$W/local.sum" "$W/slurm.sum" || { echo "FAIL: the Slurm map differs from the local one"; exit 1; }
ls "$W/slurm/work/slurm/"*.log >/dev/null || { echo "FAIL: no Slurm task logs"; exit 1; }
cmp "$W/local/pq_codebook.vlpq" "$W/slurm/pq_codebook.vlpq" || { echo "FAIL: the PQ codebooks differ"; exit 1; }
[ -f "$W/slurm/retrieval/index.vlidx" ] || { echo "FAIL: no retrieval index after the Slurm build"; exit 1; }

# Resume: a segment whose result is gone is the only one resubmitted.
rm -f "$W/slurm/work/seg0001/result.json"
"$V" map build "${common[@]}" --out "$W/slurm" --executor slurm --no-retrieval > "$W/slurm2.txt"
cat "$W/slurm2.txt"
[ "$(grep -c ' reused$' "$W/slurm2.txt")" -eq "$(( $(wc -l < "$W/local.sum") - 1 ))" ] \
  || { echo "FAIL: expected every segment but one reused"; exit 1; }
logs() { ls "$W/slurm/work/slurm/" | grep '\.log$'; }
jobs=$(logs | sed 's/_.*//' | sort -u | wc -l)
[ "$jobs" -eq 2 ] || { echo "FAIL: expected 2 arrays, found $jobs"; exit 1; }
last=$(logs | sed 's/_.*//' | sort -n | tail -1)
[ "$(logs | grep -c "^${last}_")" -eq 1 ] || { echo "FAIL: the second array ran more than one task"; exit 1; }
[ ! -e "$W/slurm/work/slurm/active_job" ] || { echo "FAIL: active_job left after the arrays ended"; exit 1; }
summary "$W/slurm" > "$W/slurm2.sum"
diff "$W/local.sum" "$W/slurm2.sum" || { echo "FAIL: the resumed Slurm map differs"; exit 1; }

# Failing tasks are reported with their Slurm logs; with no segment built the command fails.
if "$V" map build "${common[@]}" --out "$W/failing" --executor slurm --no-retrieval --colmap false > "$W/failing.txt" 2>&1; then
  echo "FAIL: a build whose every task failed exited 0"; cat "$W/failing.txt"; exit 1
fi
grep -q "log: .*/failing/work/slurm/[0-9]*_[0-9]*\.log" "$W/failing.txt" || { echo "FAIL: no Slurm log named"; cat "$W/failing.txt"; exit 1; }
echo "PASS"
