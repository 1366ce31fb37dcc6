#!/usr/bin/env bash
# Fuzz every reader in turn, one core, SECONDS_PER_TARGET each (default 600); prints executions
# and findings per target. Not in CI. Usage: fuzz/campaign.sh [seconds] [out-dir]
set -u
secs=${1:-600}
out=${2:-fuzz/findings}
here=$(cd "$(dirname "$0")" && pwd)
py=${PYTHON:-$here/../.venv/bin/python}
mkdir -p "$out"
for t in $("$py" "$here/run.py" --list); do
  (cd "$out" && "$py" "$here/run.py" "$t" -max_total_time="$secs" -timeout=2 -rss_limit_mb=4096 \
     > "$t.log" 2>&1)
  rc=$?
  runs=$(grep -o 'Done [0-9]* runs' "$out/$t.log" | grep -o '[0-9]*' || echo "?")
  echo "$t: exit $rc, ${runs} executions, findings: $(ls "$out" | grep -c -E '^(crash|timeout|oom)-' )"
done
