#!/usr/bin/env bash
# The fibres' own time step with the field's held (docs/two-way.md, "The fibres' own
# step"): flow.field_steps lets the fibres step at Δt while the DNS takes field steps of
# Δt/m, so runs that differ only in the fibres' step share the field's bits; and
# fibers[].substeps steps the fibres at Δt/k with the samples held over Δt.
#
#   scripts/fiber_step.sh            # OUT=recordings/fiber-step, ≈ 40 min on two cores
#   python3 scripts/fiber_step_tables.py recordings/fiber-step docs/figures
#
# One-way: launch/paper-1e4.toml (6 × 10⁴ fibres, fine grid) over 80.8 t+ with the fibres'
# step 0.05, 0.1, 0.2 and 0.4 t+ (fields 0.05, 0.1, 0.1 and 0.2; 0.2 also with the field's
# 0.2, the launch file's own), a state every 2 t+. Two-way: launch/two-way.toml (5.2 × 10⁴
# case-1 fibres, loading 0.4) over its first 100 t+, realisation 0 with the fibres' step
# 0.05, 0.1, 0.2 (fields 0.1 and 0.2) and 0.4, realisation 1 with 0.2 and 0.4; both also
# with coupling steps of 0.2 t+ in four fibre substeps.
set -euo pipefail
cd "$(dirname "$0")/.."
FF=${FIBERFLOW:-target/release/fiberflow}
OUT=${OUT:-recordings/fiber-step}

one_way() { # coupling step, field steps per coupling step[, fibre substeps]
    local dt=$1 m=$2 k=${3:-1} field steps every name sets=()
    field=$(python3 -c "print($dt / $m)")
    steps=$(python3 -c "print(round(80.8 / $dt))")
    every=$(python3 -c "print(round(2 / $dt))")
    name=dt-$dt-field-$field
    if [ "$k" != 1 ]; then
        name=$name-sub-$k
        for c in 1 2 3 4 5 6; do sets+=(--set "fibers.case$c.substeps=$k"); done
    fi
    "$FF" launch launch/paper-1e4.toml --out "$OUT/one-way/$name" \
        --set "run.dt_plus=$dt" --set "run.steps=$steps" --set "flow.field_steps=$m" \
        --set "recorder.states_every_steps=$every" "${sets[@]}"
}

two_way() { # realisation, coupling step, field steps per coupling step[, fibre substeps]
    local r=$1 dt=$2 m=$3 k=${4:-1} field steps per_2t name
    field=$(python3 -c "print($dt / $m)")
    name=r$r-dt-$dt-field-$field
    [ "$k" = 1 ] || name=$name-sub-$k
    steps=$(python3 -c "print(round(100 / $dt))")
    per_2t=$(python3 -c "print(round(2 / $dt))")
    "$FF" launch launch/two-way.toml --transport iceoryx2 \
        --out "$OUT/two-way/$name" --set "fibers.case1.substeps=$k" \
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
one_way 0.2 1 4
two_way 0 0.05 1
two_way 0 0.1 1
two_way 0 0.2 2
two_way 0 0.2 1
two_way 0 0.4 2
two_way 1 0.2 1
two_way 1 0.4 2
two_way 0 0.2 1 4
