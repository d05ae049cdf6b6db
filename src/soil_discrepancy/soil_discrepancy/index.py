"""One table over several ``soil_discrepancy`` reports (the full-size run's docs/discrepancy/README.md).

    python -m soil_discrepancy.index docs/discrepancy
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from soil_msgs_py import markdown_table as md

from .report import _n, headline_verdict  # the reports' way of printing a number that may be missing; their headline


def index_markdown(root: Path) -> str:
    rows = []
    for js in sorted(Path(root).glob("*/discrepancy.json")):
        rep = json.loads(js.read_text())
        case = js.parent.name
        test = rep.get("test") or {}
        before, after = (test.get("before") or {}).get("rmse"), (test.get("after") or {}).get("rmse")
        named = ", ".join(f"`{a['name']}` k = {a['k']:.4g} ± {a['k_se']:.2g}" for a in rep["selection"]["accepted"]) or "none"
        check = rep.get("hidden_check")
        hidden = "–" if check is None else ("none" if check["hidden"] is None else " + ".join(
            f"`{name}` k = {k:g}" for name, k in check.get("hidden_all") or [check["hidden"]]))
        verdict = "–" if check is None else ("correct" if check["correct"] else "**wrong**")
        pinn = (test.get("predictors") or {}).get("PINN") or {}
        soil, force = (pinn.get("comparisons") or {}).get("soil"), (pinn.get("comparisons") or {}).get("force")
        p = "–" if soil is None else f"{_n(soil['before']['rmse'])} → {_n(soil['after']['rmse'])}"
        f = "–" if force is None else f"{_n(force['before']['rmse'])} → {_n(force['after']['rmse'])}"
        ratio = f" (× {after / before:.2f})" if before and after is not None else ""
        rows.append(md.row([f"[{case}]({case}/discrepancy.md)", rep['data'].get('episodes', '–'), hidden, named, verdict,
                            f"{_n(before)} → {_n(after)}{ratio}", p, f, headline_verdict(rep)]))
    head = ["# Discrepancy workflow: full-size run", "",
            "Made by `make discrepancy` (`scripts/discrepancy_full.sh`): 108 ten-second episodes per case "
            "(4 soils × I_d {0, 40, 80} % × 3 speeds × 3 depths), an effect hidden in the simulator (fee world) "
            "or none; the workflow never reads the ground truth or the bags' plugin record. Held-out RMSE: "
            "|F_meas − F_model| over x and z on the held-out soil groups, FEE model before/after the named "
            "effect. PINN, retrained without/with the named effect (trained on the selection part plus a calibration half "
            "of each held-out group, scored on the other half): RMSE of its soil estimates pooled per soil group "
            "through the model (the physics test: one θ̂ per soil at every depth and speed) and of its output F̂.", "",
            *md.header(["case", "episodes", "hidden", "named (k ± SE)", "check", "held-out RMSE [N] before → after",
                        "PINN soil-estimate RMSE [N] before → after", "PINN F̂ RMSE [N] before → after", "verdict"])]
    return "\n".join(head + rows) + "\n"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1 or not Path(argv[0]).is_dir():
        print("usage: python -m soil_discrepancy.index REPORTS_DIR", file=sys.stderr)
        return 2
    out = Path(argv[0]) / "README.md"
    out.write_text(index_markdown(Path(argv[0])))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
