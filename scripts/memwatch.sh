#!/usr/bin/env bash
# Long-run memory check (docs/architecture.md, "Long runs: memory").
#   bash scripts/memwatch.sh OUT STEPS
# runs launch/validation/analytic-shear.toml for STEPS coupling steps over iceoryx2 into OUT
# (a state recorded every 10^4 steps, or at the end of a shorter run) and logs every node's resident memory every 2 s to
# OUT.mem, one line per node: elapsed_s node rss_kb peak_kb.
set -euo pipefail
OUT=$1
STEPS=$2
cd "$(dirname "$0")/.."
cargo build --release --quiet
B="${CARGO_TARGET_DIR:-target}/release/fiberflow"
EVERY=$(( STEPS < 10000 ? STEPS : 10000 ))
rm -rf "$OUT" "$OUT.mem"
"$B" launch launch/validation/analytic-shear.toml --transport iceoryx2 --out "$OUT" \
  --set run.steps="$STEPS" --set recorder.states_every_steps=$EVERY --set run.analyze=false \
  > "$OUT.stdout" 2> "$OUT.stderr" &
launcher=$!
t0=$(date +%s)
while kill -0 "$launcher" 2>/dev/null; do
  for p in $(pgrep -f "$OUT/config/" || true); do
    node=$(tr '\0' ' ' < "/proc/$p/cmdline" 2>/dev/null | sed -E 's|.*config/([^ ]*)\.toml.*|\1|')
    rss=$(awk '/VmRSS/{print $2}' "/proc/$p/status" 2>/dev/null || true)
    peak=$(awk '/VmHWM/{print $2}' "/proc/$p/status" 2>/dev/null || true)
    [ -n "$rss" ] && echo "$(( $(date +%s) - t0 )) $node $rss $peak" >> "$OUT.mem"
  done
  sleep 2
done
status=0
wait "$launcher" || status=$?
echo "exit $status after $(( $(date +%s) - t0 )) s" >> "$OUT.mem"
exit "$status"
