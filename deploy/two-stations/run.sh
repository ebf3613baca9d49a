#!/usr/bin/env bash
# Two ground stations sharing one fleet, on one host over loopback (ports 7501, 7502).
# Starts two routers (B connected to A), one daemon per station, and two virtual actuators
# connected at station A; queries the status of both daemons through station B's router;
# then stops everything (SIGTERM) and lists the MCAP logs. Usage: deploy/two-stations/run.sh [SECONDS]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
sw="$root/.venv/bin/servowatch"
secs="${1:-8}"
work="$(mktemp -d)"
cd "$work"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
}
trap cleanup EXIT

"$sw" router --config "$here/router-a.json5" > router-a.log 2>&1 & pids+=($!)
sleep 1
"$sw" router --config "$here/router-b.json5" > router-b.log 2>&1 & pids+=($!)
sleep 1
"$sw" run --config "$here/station-a.toml" --log logs-a/stationA.mcap > daemon-a.log 2>&1 & da=$!
"$sw" run --config "$here/station-b.toml" --log logs-b/stationB.mcap > daemon-b.log 2>&1 & db=$!
pids+=("$da" "$db")
sleep 2
for ac in AC001 AC002; do
  "$sw" actuator --scenario healthy_noise --aircraft "$ac" --actuator elevator_L \
    --connect tcp/127.0.0.1:7501 --duration "$secs" > "actuator-$ac.log" 2>&1 & pids+=($!)
done
sleep $(( secs / 2 + 1 ))
echo "== status of every daemon, asked through station B's router =="
"$sw" status --connect tcp/127.0.0.1:7502 --mode client --timeout 3 || true
sleep $(( secs / 2 + 1 ))
kill -TERM "$da" "$db"
wait "$da" || true
wait "$db" || true
echo "== logs (in $work) =="
ls -l logs-a logs-b
"$sw" replay logs-a/stationA.mcap --json > replay-a.json && head -c 300 replay-a.json; echo
"$sw" replay logs-b/stationB.mcap --json > replay-b.json && head -c 300 replay-b.json; echo
