#!/usr/bin/env bash
# The fuzz campaign (not in CI): every reader in turn, RUNS executions each (default 1 000 000),
# 2 s per input (a slower input is a hang), 2 GB of memory (more is an OOM finding).
#
#   nice -n 19 fuzz/campaign.sh [-n RUNS] [-t SECONDS] [-o OUT] [TARGET ...]
#
# -t caps the time per target (default: none). Unnamed exceptions are kept in OUT/TARGET/
# (unnamed-*, with the traceback) and the target goes on; a crash, hang or OOM ends the
# process (libFuzzer writes OUT/TARGET/crash-*, timeout-*, oom-*) and the target restarts from
# its corpus, at most 5 times. Prints and writes OUT/summary.md: executions, exec/s and
# findings per target. Targets default to every one (fuzz/run.py --list).
set -u
runs=1000000 secs=0 out=fuzz/findings
while getopts n:t:o: opt; do
  case $opt in
    n) runs=$OPTARG ;;
    t) secs=$OPTARG ;;
    o) out=$OPTARG ;;
    *) echo "usage: $0 [-n RUNS] [-t SECONDS] [-o OUT] [TARGET ...]" >&2; exit 2 ;;
  esac
done
shift $((OPTIND - 1))
here=$(cd "$(dirname "$0")" && pwd)
py=${PYTHON:-$here/../.venv/bin/python}
targets=${*:-$("$py" "$here/run.py" --list)}
mkdir -p "$out" && out=$(cd "$out" && pwd)
summary=$out/summary.md
# the targets' input files (fuzz/targets.py: scratch_dir), in memory where possible
shm=/dev/shm; [ -d $shm ] && [ -w $shm ] || shm=${TMPDIR:-/tmp}
SCANREG_FUZZ_SCRATCH=$(mktemp -d "$shm/scanreg-fuzz-campaign-XXXXXX") && export SCANREG_FUZZ_SCRATCH
trap 'rm -rf "$SCANREG_FUZZ_SCRATCH"' EXIT
count() { find "$1" -maxdepth 1 -name "$2-*" ! -name '*.txt' | wc -l; }
{
  echo "commit $(git -C "$here" rev-parse --short HEAD), $(date -u +%FT%TZ), -n $runs -t $secs"
  echo
  echo "| target | executions | seconds | exec/s | crashes | hangs | OOMs | unnamed exceptions | $runs runs |"
  echo "|---|---:|---:|---:|---:|---:|---:|---:|---|"
} > "$summary"
for t in $targets; do
  dir=$out/$t
  mkdir -p "$dir"
  total=0 spent=0 unnamed=0 restarts=0
  while ((total < runs && restarts <= 5)); do
    limit=()
    if ((secs > 0)); then
      ((secs - spent <= 0)) && break
      limit=(-max_total_time=$((secs - spent)))
    fi
    log=$dir/run-$restarts.log
    rm -f "$dir/progress.json"
    start=$(date +%s)
    "$py" "$here/run.py" "$t" --findings "$dir" -runs=$((runs - total)) "${limit[@]}" \
      -timeout=2 -rss_limit_mb=2048 -artifact_prefix="$dir/" -print_final_stats=1 > "$log" 2>&1
    rc=$?
    spent=$((spent + $(date +%s) - start))
    # libFuzzer's own count when it printed one, else the last progress.json (<= 500 short)
    read -r n u < <("$py" - "$log" "$dir/progress.json" << 'EOF'
import json, re, sys
log, prog = sys.argv[1:]
p = {"executions": 0, "unnamed": 0}
try:
    p = json.load(open(prog))
except (OSError, ValueError):
    pass
m = re.findall(r"stat::number_of_executed_units: *(\d+)", open(log, errors="replace").read())
print(max([int(x) for x in m] + [p["executions"]]), p["unnamed"])
EOF
    )
    total=$((total + n)) unnamed=$((unnamed + u))
    ((rc == 0)) && break
    restarts=$((restarts + 1))
    echo "$t: run $restarts ended with exit $rc after $n executions (see $log)" >&2
  done
  rate=$((spent > 0 ? total / spent : 0))
  met=$( ((total >= runs)) && echo met || echo "NOT met" )
  row="| $t | $total | $spent | $rate | $(count "$dir" crash) | $(count "$dir" timeout) | $(count "$dir" oom) | $unnamed | $met |"
  echo "$row" | tee -a "$summary"
done
