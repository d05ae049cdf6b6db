#!/usr/bin/env bash
# Full-size run of the discrepancy workflow, reproducible from documented seeds:
#   make discrepancy        (or: scripts/discrepancy_full.sh [control soil_inertia ...])
# For each case: generate a fee-world dataset (4 soils x I_d {0,40,80} x 3 speeds x 3 depths,
# 108 ten-second episodes; skipped if present) with one effect hidden in the simulator (or none:
# the control), run soil_discrepancy on it (which never reads the ground truth), retrain the
# PINN with the named effect, and write the report under docs/discrepancy/<case>/ (committed).
# Case default_world: the same grid in the default world, whose extra effects (surcharge pile,
# penetration, contact damping and friction, particles, compaction, noise) are the "real machine":
# nothing is known to be hidden, the report says what the workflow makes of it.
# Case default_world_unlabelled: the same bags as default_world read as a real machine's, without
# a soil label (--group-by gamma: episodes of one measured unit weight share θ); the PINN is
# retrained there too when something is named (~1.5 min; the whole run stays near 10 of its 15).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-.venv/bin}
DATA=${DATA:-bags/disc_full}
OUT=${OUT:-docs/discrepancy}
PINN_EPOCHS=${PINN_EPOCHS:-30}
PINN_SEEDS=${PINN_SEEDS:-3}
GRID=(--relative-densities 0,40,80 --speeds 0.3,0.65,1.0 --depths 0.1,0.175,0.25 --seeds 1 --seed-base 100 --quiet)
hidden() {  # case -> "term k" hidden in the simulator ("" for the control)
    case "$1" in
        control) echo "" ;;
        soil_inertia) echo "soil_inertia 4" ;;
        compaction) echo "compaction_hardening 0.06" ;;
        rate_strength) echo "rate_strength 8000" ;;
        default_world|default_world_unlabelled) echo "" ;;
        *) echo "unknown case $1" >&2; exit 2 ;;
    esac
}
for case in ${*:-control soil_inertia compaction rate_strength default_world default_world_unlabelled}; do
    term="" k=""
    spec=$(hidden "$case")  # an unknown case stops the run here (set -e)
    read -r term k <<< "$spec" || true
    mode=fee check=(--hidden "${term:-none}${k:+=$k}") data=$case grouping=()
    case "$case" in default_world*) mode=default check=() data=default_world ;; esac
    case "$case" in *_unlabelled) grouping=(--group-by gamma) ;; esac
    if [ ! -f "$DATA/$data/dataset.json" ]; then
        plugin=()
        [ -n "${term:-}" ] && plugin=(--plugin "soil_physics.force_terms:plugin term=$term k=$k")
        "$BIN/soil_sim_batch" "${GRID[@]}" --mode "$mode" --out "$DATA/$data" "${plugin[@]}"
    fi
    "$BIN/soil_discrepancy" "$DATA/$data" --out "$OUT/$case" --pinn-epochs "$PINN_EPOCHS" --pinn-seeds "$PINN_SEEDS" \
        --quiet "${check[@]}" "${grouping[@]}"
done
"$BIN/python" -m soil_discrepancy.index "$OUT"
echo "reports: $OUT/README.md and $OUT/<case>/discrepancy.md"
