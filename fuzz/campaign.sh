#!/usr/bin/env bash
# Fuzz every reader in turn, one core, SECONDS per target (default 600); prints executions and
# findings per target (libFuzzer stops a target at its first finding, written to
# OUT/TARGET/crash-*). Not in CI. Usage: fuzz/campaign.sh [seconds] [out-dir]
set -u
secs=${1:-600}
out=$(mkdir -p "${2:-fuzz/findings}" && cd "${2:-fuzz/findings}" && pwd)
here=$(cd "$(dirname "$0")" && pwd)
py=${PYTHON:-$here/../.venv/bin/python}
for t in $("$py" "$here/run.py" --list); do
  mkdir -p "$out/$t"
  (cd "$out/$t" && "$py" "$here/run.py" "$t" -max_total_time="$secs" -timeout=2 \
     -rss_limit_mb=4096 -print_final_stats=1 > "$out/$t.log" 2>&1)
  rc=$?
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$out/$t.log" | grep -o '[0-9]*$')
  echo "$t: exit $rc, ${runs:-?} executions, findings: $(ls "$out/$t" | grep -c -E '^(crash|timeout|oom|slow-unit)-')"
done
