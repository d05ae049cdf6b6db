#!/usr/bin/env bash
# Is each shipped fused-posterior config what the calibration gives with today's code?
#   make calibration-check        (or: scripts/check_calibration.sh [fee|default ...]; 5 min fee, 13 min default, on 2 cores)
# A change to how the posterior takes evidence changes its posteriors, and a config calibrated
# before it keeps laws chosen for others (the default world's z forecast law, 2026-12-04). This
# reruns `pinn_fusion_calibrate` and `soil_planner_calibrate` with the shipped arguments into a
# temporary file and compares every field with the shipped config; exit 1 names what differs
# (recalibrate: `make models`, or the two commands of scripts/train_models.sh for that world).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-.venv/bin}
SHIP=src/pinn_estimator/pinn_estimator/models
source scripts/fusion_args.sh
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
status=0
for w in ${*:-fee default}; do
    mapfile -t args < <(fusion_args "$w")
    echo "calibration-check: $w world ..."
    "$BIN/pinn_fusion_calibrate" --world "$w" "${args[@]}" --out "$tmp/fusion_$w.json" > "$tmp/$w.log"
    "$BIN/soil_planner_calibrate" --world "$w" --config "$tmp/fusion_$w.json" >> "$tmp/$w.log"
    "$BIN/python" - "$SHIP/fusion_$w.json" "$tmp/fusion_$w.json" <<'PY' || status=1
import json, sys
shipped, fresh = (json.load(open(p)) for p in sys.argv[1:3])
differ = sorted(k for k in set(shipped) | set(fresh) if shipped.get(k) != fresh.get(k))
for k in differ:
    print(f"  {k}: shipped {shipped.get(k)!r}, calibrated now {fresh.get(k)!r}")
print(f"  {sys.argv[1]}: " + ("as calibrated now" if not differ else f"{len(differ)} field(s) differ: recalibrate"))
sys.exit(1 if differ else 0)
PY
done
exit $status
