#!/usr/bin/env bash
# Soak: run the process group for N actions (default 1 000 000) at the fastest real-time
# factor, sampling each child's resident memory every 10 s into rss.csv, and keep the
# controller's report (latency percentiles, budget misses, allocations) in controller.json.
#   bash scripts/soak.sh [ACTIONS] [OUT_DIR]
# ACTING_CPU / PLANNER_CPU, if set, place the controller's two threads (its acting_cpu and
# planner_cpu keys: a CPU, auto or none), e.g. ACTING_CPU=none PLANNER_CPU=none to run them
# unpinned; unset, the controller's default (auto: pinned, blocking on >= 2 CPUs) applies.
set -euo pipefail
actions="${1:-1000000}"
out="${2:-soak-$(date +%Y%m%d-%H%M%S)}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
cd "$(dirname "$0")/.."
cargo build --release -p tes
# TOML strings ("1", "auto", "none"): the keys take a CPU written either way.
placement=""
[ -n "${ACTING_CPU:-}" ] && placement+="acting_cpu = \"$ACTING_CPU\""$'\n'
[ -n "${PLANNER_CPU:-}" ] && placement+="planner_cpu = \"$PLANNER_CPU\""$'\n'
cat > "$out/soak.toml" <<TOML
[launch]
episodes = 100000000
service_prefix = "soak-$$/"
run_dir = "$out/run"
[perception]
actions = $actions
[controller]
library = "$out/library.tesl"
report = "$out/controller.json"
warmup_actions = 10000
$placement
[bridge.ipc]
warmup_commands = 10000
latency_report = "$out/bridge.json"
latency_windows = "$out/bridge-windows.csv"
TOML
echo "seconds,role,rss_kib" > "$out/rss.csv"
start=$(date +%s)
TES_DATA_DIR="$out" ./target/release/tes launch --config "$out/soak.toml" > "$out/launch.log" 2>&1 &
launcher=$!
while kill -0 "$launcher" 2>/dev/null; do
  sleep 10
  now=$(( $(date +%s) - start ))
  for pid in $(pgrep -P "$launcher" || true); do
    role=$(tr '\0' ' ' < "/proc/$pid/cmdline" 2>/dev/null | awk '{print $3}')
    rss=$(awk '/VmRSS/{print $2}' "/proc/$pid/status" 2>/dev/null || true)
    [ -n "$rss" ] && echo "$now,$role,$rss" >> "$out/rss.csv"
  done
done
wait "$launcher"
echo "done in $(( $(date +%s) - start )) s; see $out/{controller.json,bridge.json,rss.csv,launch.log}"
tail -n 3 "$out/launch.log"
