#!/usr/bin/env bash
# The fibres' own time step with the field's held (docs/two-way.md, "Field steps per
# coupling step"): flow.field_steps lets the fibres step at Δt while the DNS takes field
# steps of Δt/m, so runs that differ only in the fibres' step share the field's bits.
#
#   scripts/fiber_step.sh            # OUT=recordings/fiber-step, ≈ 40 min on two cores
#   python3 scripts/fiber_step_tables.py recordings/fiber-step docs/figures
#
# One-way: launch/paper-1e4.toml (6 × 10⁴ fibres, fine grid) over 80.8 t+ with the fibres'
# step 0.05, 0.1, 0.2 and 0.4 t+ (fields 0.05, 0.1, 0.1 and 0.2; 0.2 also with the field's
# 0.2, the launch file's own), a state every 2 t+. Two-way: launch/two-way.toml (5.2 × 10⁴
# case-1 fibres, loading 0.4) over its first 100 t+, realisation 0 with the fibres' step
# 0.05, 0.1, 0.2 (fields 0.1 and 0.2) and 0.4, realisation 1 with 0.2 and 0.4.
set -euo pipefail
cd "$(dirname "$0")/.."
FF=${FIBERFLOW:-target/release/fiberflow}
OUT=${OUT:-recordings/fiber-step}

one_way() { # fibres' step, field steps per coupling step
    local dt=$1 m=$2 field steps every
    field=$(python3 -c "print($dt / $m)")
    steps=$(python3 -c "print(round(80.8 / $dt))")
    every=$(python3 -c "print(round(2 / $dt))")
    "$FF" launch launch/paper-1e4.toml --out "$OUT/one-way/dt-$dt-field-$field" \
        --set "run.dt_plus=$dt" --set "run.steps=$steps" --set "flow.field_steps=$m" \
        --set "recorder.states_every_steps=$every"
}

two_way() { # realisation, fibres' step, field steps per coupling step (a status every 2 t+)
    local r=$1 dt=$2 m=$3 field steps per_2t
    field=$(python3 -c "print($dt / $m)")
    steps=$(python3 -c "print(round(100 / $dt))")
    per_2t=$(python3 -c "print(round(2 / $dt))")
    "$FF" launch launch/two-way.toml --transport iceoryx2 \
        --out "$OUT/two-way/r$r-dt-$dt-field-$field" \
        --set "run.realisation=$r" --set "run.dt_plus=$dt" --set "run.steps=$steps" \
        --set "flow.field_steps=$m" --set "recorder.states_every_steps=$steps" \
        --set "fibers.case1.metrics_every_steps=$((5 * per_2t))" \
        --set "flow.status_every_steps=$per_2t" --set "flow.profiles_every_steps=$steps" \
        --set "flow.slices_every_steps=$((5 * per_2t))"
}

one_way 0.05 1
one_way 0.1 1
one_way 0.2 2
one_way 0.2 1
one_way 0.4 2
two_way 0 0.05 1
two_way 0 0.1 1
two_way 0 0.2 2
two_way 0 0.2 1
two_way 0 0.4 2
two_way 1 0.2 1
two_way 1 0.4 2
