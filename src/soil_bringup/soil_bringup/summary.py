"""The demo's summary as text: the console table, ``summary.md`` and the throughput sentence.

One row per episode and an overall row, from the figures ``scoring`` computes (MAE over valid
estimates; forces in kN and % of the mean measured |F|, parameters in deg / kPa).
"""
from __future__ import annotations

from soil_msgs_py import markdown_table as md
from soil_msgs_py.params import WINDOW_SAMPLES

JSON_NAME = "summary.json"
MARKDOWN_NAME = "summary.md"
FIGURE_NAME = "online_estimates.png"

TABLE_COLUMNS = (  # (header, width, getter)
    ("episode", 13, lambda r: r["soil"] if "soil" in r else r["name"]),
    ("I_d %", 5, lambda r: f"{r['relative_density_pct']:.0f}" if "relative_density_pct" in r else ""),
    ("valid", 5, lambda r: f"{r['valid_estimates']}"),
    ("ticks %", 7, lambda r: f"{r['pct_ticks_valid']:.1f}"),
    ("Fx MAE kN (%)", 13, lambda r: f"{r['force']['mae_x_n'] / 1e3:.2f} ({r['force']['mae_x_pct_measured']:.0f})"),
    ("Fz MAE kN (%)", 13, lambda r: f"{r['force']['mae_z_n'] / 1e3:.2f} ({r['force']['mae_z_pct_measured']:.0f})"),
    ("φ deg", 6, lambda r: f"{r['params']['phi_mae_deg']:.1f}"),
    ("c kPa", 6, lambda r: f"{r['params']['c_mae_kPa']:.2f}"),
    ("δ deg", 6, lambda r: f"{r['params']['delta_mae_deg']:.1f}"),
    ("β deg", 6, lambda r: f"{r['params']['beta_mae_deg']:.1f}"),
)


def table_text(rows: list[dict], total: dict) -> str:
    """Console table: one row per episode, a rule, the overall row (MAE over valid estimates)."""
    def line(cells):
        return "  ".join(f"{c:<{w}}" if i == 0 else f"{c:>{w}}" for i, (c, (_, w, _)) in enumerate(zip(cells, TABLE_COLUMNS)))
    head = line([h for h, _, _ in TABLE_COLUMNS])
    body = [line([get(r) for _, _, get in TABLE_COLUMNS]) for r in rows]
    return "\n".join([head, "-" * len(head), *body, "-" * len(head), line([get(total) for _, _, get in TABLE_COLUMNS])])


def markdown(report: dict) -> str:
    """``summary.md``: the run, the error table, mean estimates vs truth, the soil fused along each
    episode, the planner's question (``demo_forecast``, when the run made it), throughput and the figure."""
    run, rows, total = report["run"], report["episodes"], report["overall"]
    lines = [
        "# Online estimation demo", "",
        f"{len(rows)} episode(s) of {run['duration_s']:g} s"
        + (f" at {run['target_depth_m']:g} m and {run['target_speed_m_s']:g} m/s" if "target_depth_m" in run else "")
        + f", pacing {run['pacing']}"
        + (f" x{run['rate']:g}" if run["pacing"] == "realtime" else "")
        + f", {run['world_mode'] or 'default'} world; checkpoint `{run['checkpoint']}`. "
        f"Run wall time {run['wall_s']:.1f} s (launch {run['launch_s']:.1f} s). Bags: `{run['bags']}`.", "",
        "Errors are mean absolute errors over the valid estimates of each episode (each matched to the tick it is "
        "stamped with); forces as in paper §3.2 (% of the mean measured |F|), parameters against the "
        "pseudo-ground truth. The paper's parameter targets apply for I_d <= 60 % (soil failure assumption).", "",
        "| episode | I_d [%] | valid estimates | ticks with one [%] | Fx MAE [kN] (% meas.) | Fz MAE [kN] (% meas.) "
        "| φ MAE [deg] | c MAE [kPa] | δ MAE [deg] | β MAE [deg] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows + [total]:
        cells = [get(r) for _, _, get in TABLE_COLUMNS]
        if r is total:
            cells[0] = "**overall**"
        lines.append(md.row(cells))
    lines += ["", "Mean estimate (truth) over the valid estimates:", "",
              "| episode | I_d [%] | φ [deg] | c [kPa] | δ [deg] | β [deg] |", "|---|---|---|---|---|---|"]
    for r in rows:
        e, t = r["estimate_mean"], r["truth_mean"]
        lines.append(md.row([r['soil'], f"{r['relative_density_pct']:.0f}", *(
            f"{e[k]:.{2 if k.startswith('c_') else 1}f} ({t[k]:.{2 if k.startswith('c_') else 1}f})" for k in e)]))
    fused = [r for r in rows if r.get("fused_end")]
    if fused:
        lines += ["", "The soil fused along each episode (the posterior its last estimate carried: mean ± std, truth in "
                  "brackets; ✓: the 90 % interval holds the truth):", "",
                  "| episode | I_d [%] | stretches | φ [deg] | c [kPa] | δ [deg] |", "|---|---|---|---|---|---|"]
        for r in fused:
            f = r["fused_end"]
            cells = []
            for p, unit, digits in (("phi", "deg", 1), ("c", "kPa", 2), ("delta", "deg", 1)):
                v = f[p]
                cells.append(f"{v[f'mean_{unit}']:.{digits}f} ± {v[f'std_{unit}']:.{digits}f} ({v[f'truth_{unit}']:.{digits}f})"
                             + (" ✓" if v["in_90"] else ""))
            lines.append(md.row([r['soil'], f"{r['relative_density_pct']:.0f}", f['stretches'], *cells]))
    forecast = report.get("forecast")
    if forecast:
        from .demo_forecast import markdown_lines

        lines += ["", *(markdown_lines(forecast) if "skipped" not in forecast
                        else [f"The forecast at other depths was skipped: {forecast['skipped']}."])]
    lines += ["", f"Throughput: {throughput_text(run)}; {total['pct_ticks_valid']:.1f} % of ticks have a valid estimate "
              f"({total['pct_full_window_ticks_valid']:.1f} % of the ticks that end a full {WINDOW_SAMPLES}-sample window).",
              "", f"![online estimates]({FIGURE_NAME})", ""]
    return "\n".join(lines)


def throughput_text(run: dict) -> str:
    """Valid estimates per simulated second, per wall second while estimating and over the launch."""
    live = run.get("estimates_per_wall_s_estimating")
    per_launch = run.get("estimates_per_launch_s")
    return (f"{run['valid_estimates']} valid estimates: {run['estimates_per_sim_s']:.1f} per simulated second"
            + (f", {live:.1f}/s of wall time while estimating" if live else "")
            + (f", {per_launch:.1f}/s over the whole launch (with start-up and episode hand-overs)" if per_launch else ""))
