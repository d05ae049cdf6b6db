#!/usr/bin/env bash
# Reproduce the shipped models and their evaluation reports from documented seeds.
#   make models            (or: scripts/train_models.sh [fee|default ...])
# For each world: generate the §3.1-sized dataset (seeded, skipped if present), train the PINN
# and the physics-free baseline side by side (one thread each, same seed -> same by-episode
# split), then evaluate both with the classical fit on the test split. The PINN checkpoint,
# its report (.md/.json) and figure are copied into the package (pinn_estimator/models/).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-.venv/bin}
OUT=${OUT:-out/models}
SHIP=src/pinn_estimator/pinn_estimator/models
SEED=${SEED:-0}
TRAIN_ARGS=${TRAIN_ARGS:---epochs 80 --stride 4 --patience 10 --max-minutes 7}
source scripts/fusion_args.sh
mkdir -p "$OUT" "$SHIP"
for w in ${*:-fee default}; do
    data=bags/d_$w
    [ -f "$data/dataset.json" ] || "$BIN/soil_sim_batch" --mode "$w" --out "$data" --quiet
    "$BIN/python" -c "from pinn_estimator.dataset import load_dataset; load_dataset('$data', workers=2)"  # fill the cache once
    "$BIN/pinn_train" --data "$data" --out "$OUT/pinn_$w.pt" --kind pinn --seed "$SEED" --threads 1 --quiet --overwrite $TRAIN_ARGS > "$OUT/pinn_$w.log" 2>&1 &
    p1=$!
    "$BIN/pinn_train" --data "$data" --out "$OUT/physics_free_$w.pt" --kind physics_free --seed "$SEED" --threads 1 --quiet --overwrite $TRAIN_ARGS > "$OUT/physics_free_$w.log" 2>&1 &
    p2=$!
    wait $p1 || { cat "$OUT/pinn_$w.log"; exit 1; }
    wait $p2 || { cat "$OUT/physics_free_$w.log"; exit 1; }
    # models/fusion_<world>.json, used by pinn_eval's forecast, with each world's arguments
    # (scripts/fusion_args.sh; `make calibration-check` compares the shipped configs with them)
    mapfile -t fargs < <(fusion_args "$w")
    "$BIN/pinn_fusion_calibrate" --world "$w" "${fargs[@]}" > "$OUT/fusion_$w.log"
    # the planner's bound law, calibrated on the same posteriors, into the same config
    "$BIN/soil_planner_calibrate" --world "$w" >> "$OUT/fusion_$w.log"
    "$BIN/pinn_eval" --checkpoint "$OUT/pinn_$w.pt" --physics-free "$OUT/physics_free_$w.pt" --data "$data" \
      --out "$OUT" --name "pinn_${w}_report" --quiet > /dev/null
    cp "$OUT/pinn_$w.pt" "$OUT/pinn_${w}_report.md" "$OUT/pinn_${w}_report.json" "$OUT/pinn_${w}_report_params.png" \
       "$OUT/pinn_${w}_curve.png" "$SHIP/"
    echo "$w: $(grep -c '| yes |' "$OUT/pinn_${w}_report.md") targets met, $(grep -c '| \*\*no\*\* |' "$OUT/pinn_${w}_report.md") not; report $SHIP/pinn_${w}_report.md"
done
