#!/usr/bin/env bash
# The floor's soak: the raw iceoryx2 two-hop relay of `tes bench latency` (no work, the same
# payloads and wait strategy) for N round trips at the process group's soak cadence, to count
# how many times the machine itself misses the 1 ms budget over as many actions as
# scripts/soak.sh runs. Writes floor.json (the sink's latency report) into OUT_DIR.
#   bash scripts/floor-soak.sh [MESSAGES] [OUT_DIR]
# GAP_US: pause between a round trip and the next (default 1850, the soak's ~1.9 ms cycle);
# WAIT: block (default), spin or spin-then-block; HOP_CPU, if set, pins the hop as
# ACTING_CPU pins the controller's acting thread in scripts/soak.sh.
set -euo pipefail
messages="${1:-1000000}"
out="${2:-floor-soak-$(date +%Y%m%d-%H%M%S)}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
cd "$(dirname "$0")/.."
cargo build --release -p tes
cat > "$out/relay.toml" <<TOML
service_prefix = "floor-soak-$$/"
wait = "${WAIT:-block}"
messages = $messages
warmup = 10000
budget_us = 1000
report = "$out/floor.json"
gap_us = ${GAP_US:-1850}
${HOP_CPU:+hop_cpu = $HOP_CPU}
TOML
pids=()
cleanup() { kill "${pids[@]}" 2>/dev/null || true; }
trap cleanup EXIT
start=$(date +%s)
# The receivers first, as `tes bench latency` starts them.
for role in relay-sink relay-hop relay-source; do
  ./target/release/tes child "$role" --config "$out/relay.toml" > "$out/$role.log" 2>&1 &
  pids+=("$!")
  sleep 0.5
done
# The source ends the run; the others stop when it is gone (idle timeout) or at the trap.
wait "${pids[2]}"
wait "${pids[0]}" || true
echo "done in $(( $(date +%s) - start )) s; see $out/floor.json"
cat "$out/floor.json"
