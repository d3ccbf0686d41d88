#!/bin/sh
# A longer chaos soak of the two-launcher run (tests/chaos.rs): TRIALS seeded trials from
# seed FIRST (defaults 100 and 1). Each trial prints "ok: …" or "FAILED: …" with its seed;
# FIBERFLOW_CHAOS_SEED=<seed> FIBERFLOW_CHAOS_TRIALS=1 replays one.
#   tests/scripts/chaos-soak.sh [TRIALS] [FIRST]
set -eu
cd "$(dirname "$0")/../.."
FIBERFLOW_CHAOS_TRIALS="${1:-100}" FIBERFLOW_CHAOS_SEED="${2:-1}" \
  exec cargo test --release -p fiberflow --test chaos -- --nocapture
