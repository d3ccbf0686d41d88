#!/usr/bin/env bash
# The runs of the drag study (docs/realisations.md): realisations of the unladen channel and
# of case-1 fibres two-way at mass loading 0.4 and 1.0, each 2500 t+ of launch/two-way.toml
# (the first 500 the transient, the last 2000 the statistics: two batches of 1000 t+, long
# enough to be independent), one after another; the laden fibres in four substeps per
# coupling step (fibers[].substeps, docs/two-way.md, "The fibres' own step"). A run
# stopped half-way resumes from its newest checkpoint; a finished one is skipped, so the
# script can be started again after any stop.
#
#   scripts/drag-realisations.sh [SET:FIRST-LAST ...]
#     SET: unladen, 0.4 or 1.0 (default: unladen:1-6 0.4:1-4 1.0:1-4)
#   FIBERFLOW=path/to/fiberflow  OUT=recordings/drag  TRANSPORT=iceoryx2
#
# Each finished run's flow part (announcement, flow status and profiles, first and last
# states) goes to recordings/drag-flow/NAME-rI/run.mcap. Then, for example:
#   fiberflow analyze recordings/drag-flow/two-way-0.4-r{1,2,3,4} \
#     --unladen recordings/drag-flow/unladen-r{1,2,3,4,5,6} --transient-plus 500 --batches 2
set -euo pipefail
cd "$(dirname "$0")/.."
FF=${FIBERFLOW:-target/release/fiberflow}
OUT=${OUT:-recordings/drag}
TRANSPORT=${TRANSPORT:-iceoryx2}
LAUNCH=launch/two-way.toml
common=(--set run.steps=12500 --set run.analyze=false --set 'run.fiber_scheduling="normal"')
# the flow part of each finished run (scripts/flow_part.py), small enough to commit
KEEP=${KEEP:-recordings/drag-flow}

sets_of() {
    case "$1" in
    unladen) echo "--set run.coupling=\"one-way\" --set fibers.case1.placement.count=10" ;;
    0.4) echo "--set fibers.case1.placement.count=52000 --set fibers.case1.substeps=4" ;;
    1.0) echo "--set fibers.case1.placement.count=131000 --set fibers.case1.substeps=4" ;;
    *) echo "unknown set $1 (unladen, 0.4 or 1.0)" >&2; exit 2 ;;
    esac
}

run_one() {
    local set=$1 i=$2 name dir
    if [ "$set" = unladen ]; then name=unladen; else name=two-way-$set; fi
    dir=$OUT/$name-r$i
    if [ -e "$dir/logs/study.done" ]; then
        echo "$dir: done"
        return
    fi
    # shellcheck disable=SC2046
    local args=("${common[@]}" --set "run.realisation=$i" $(sets_of "$set"))
    mkdir -p "$OUT"
    if [ -d "$dir/checkpoints" ]; then
        echo "$dir: resuming"
        "$FF" launch "$LAUNCH" --transport "$TRANSPORT" --resume "$dir" "${args[@]}"
    else
        echo "$dir: starting"
        rm -rf "$dir"
        "$FF" launch "$LAUNCH" --transport "$TRANSPORT" --out "$dir" "${args[@]}"
    fi
    date -u +%FT%TZ >"$dir/logs/study.done"
    mkdir -p "$KEEP/$name-r$i"
    python3 scripts/flow_part.py "$dir/run.mcap" "$KEEP/$name-r$i/run.mcap"
}

plan=("$@")
[ ${#plan[@]} -gt 0 ] || plan=(unladen:1-6 0.4:1-4 1.0:1-4)
for p in "${plan[@]}"; do
    set=${p%%:*}
    range=${p#*:}
    for i in $(seq "${range%-*}" "${range#*-}"); do
        run_one "$set" "$i"
    done
done
