"""The forecast's pairs on a machine's bags: episodes without a soil label are paired by their
measured unit weight γ, never across soils (``forecast.steady_parts``)."""
from __future__ import annotations

from dataclasses import replace

from pinn_estimator.dataset import load_dataset
from pinn_estimator.forecast import pair_indices, steady_parts
from soil_bag_tools.bag_io import write_episode
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig


def test_unlabelled_episodes_pair_only_within_one_unit_weight(tmp_path):
    specs = [EpisodeSpec(soil, 20.0, 0.6, depth, seed=k, duration_s=5.0)
             for k, (soil, depth) in enumerate((s, d) for s in ("Sand", "Clay") for d in (0.1, 0.2))]
    episodes = list(run_episodes(SimConfig(world_mode="fee"), specs))
    for ep in episodes:
        write_episode(tmp_path / "labelled" / ep.meta.name, ep)
        ep.meta = replace(ep.meta, soil="unknown")  # a machine's bag: no soil name
        write_episode(tmp_path / "unlabelled" / ep.meta.name.replace("unknown", ep.meta.name), ep)

    def soils_of_pairs(folder):
        parts = steady_parts(load_dataset(tmp_path / folder, cache=False))
        return parts, [(parts[a].soil, parts[b].soil, parts[a].known["gamma"], parts[b].known["gamma"])
                       for a, b in pair_indices(parts)]

    labelled, pairs = soils_of_pairs("labelled")
    assert len(pairs) == 4 and all(a == b for a, b, *_ in pairs)
    parts, pairs = soils_of_pairs("unlabelled")
    assert len(pairs) == 4, "each soil's two depths, each way; never sand with clay"
    assert all(a == b and a.startswith("γ≈") and abs(ga / gb - 1) < 0.002 for a, b, ga, gb in pairs), pairs
    assert len({p.soil for p in parts}) == 2


def test_a_label_naming_two_soils_is_told_apart_by_the_ground_truth(tmp_path):
    """A soil of the user's soil file named like a catalogue soil: its bags and the catalogue's
    paired as one soil, a forecast 1061 % off. One soil at one density starts with one (φ, c)."""
    from soil_physics.soils import load_soil_file

    soils = tmp_path / "site.yaml"
    soils.write_text("soils:\n  - {name: Sand, phi_deg: [10, 12], cohesion_pa: [8000, 12000], "
                     "unit_weight_n_m3: [19000, 21000]}\n")
    mine = load_soil_file(soils).soils
    for custom, seed0 in ((None, 0), (mine, 10)):
        specs = [EpisodeSpec("Sand", 50.0, 0.6, depth, seed=seed0 + k, duration_s=5.0) for k, depth in enumerate((0.06, 0.1))]
        for ep in run_episodes(SimConfig(world_mode="fee"), specs, custom_soils=custom):
            write_episode(tmp_path / "bags" / ep.meta.name, ep)
    parts = steady_parts(load_dataset(tmp_path / "bags", cache=False))
    labels = sorted({p.soil for p in parts if p is not None})
    assert len(labels) == 2 and all(label.startswith("Sand (φ ") for label in labels), labels
    pairs = [(parts[a].soil, parts[b].soil) for a, b in pair_indices(parts)]
    assert len(pairs) == 4 and all(a == b for a, b in pairs), pairs  # each soil's two depths, each way


def test_the_forecast_report_says_when_episodes_were_paired_by_unit_weight():
    from pinn_estimator.forecast import markdown

    report = {"data": "bags/machine", "pairs": 4, "episodes": 4, "worlds": ["fee"], "forecast": {}}
    labelled = markdown({**report, "unlabelled": 0})[0]
    assert "same soil and density:" in labelled and "γ" not in labelled
    blind = markdown({**report, "unlabelled": 4})[0]
    assert "4 of the episodes carry no soil label" in blind and "measured unit weight γ" in blind


def test_the_forecast_report_says_what_it_did_not_pair_and_how_loosely_few_pairs_know_a_coverage():
    """An outside tester's 48 off-grid episodes gave 188 pairs where 192 were expected, the rest
    unsaid; and 16 pairs' 81 / 25 % coverage read as a finding."""
    from types import SimpleNamespace

    from pinn_estimator.forecast import markdown, same_depth_pairs

    def part(d):
        return SimpleNamespace(world="fee", soil="Clay", relative_density_pct=30.0, known={"d": d})

    # 0.10 and 0.11 m are one depth (less than 1.2x apart): 2 ordered pairs left out; 0.2 m pairs with both
    parts = [part(0.10), part(0.11), part(0.20), None]
    assert same_depth_pairs(parts) == 2
    report = {"data": "bags/x", "pairs": 16, "episodes": 4, "worlds": ["fee"], "forecast": {}, "unlabelled": 0,
              "no_steady_part": 1, "same_depth_pairs": 2}
    intro = markdown(report)[0]
    assert ("Not paired: 1 episode(s) without a steady cut of one soil in their second half; 2 ordered pair(s) of one soil and "
            "density whose steady depths are less than 1.2× apart (not another depth).") in intro
    assert "With 16 pairs a coverage is known to at least ±12 points at 50 % (±8 at 90 %)." in intro
    many = markdown({**report, "pairs": 72, "no_steady_part": 0, "same_depth_pairs": 0})[0]
    assert "Not paired" not in many and "coverage is known" not in many


def test_a_row_scored_on_fewer_pairs_than_the_header_says_so():
    """The header said "44 pairs" for every row, where two rows were scored on 42 (their forecast
    was undefined in two): the JSON alone told them apart."""
    from pinn_estimator.forecast import markdown

    def axes(pairs):
        row = {"pairs": pairs, "mean_abs_pct": 1.0, "bias_pct": 0.0}
        return {a: {"all": row, "deeper": row, "shallower": row} for a in ("x", "z")}

    report = {"data": "bags/live", "pairs": 44, "episodes": 24, "worlds": ["default"],
              "forecast": {"pinn": axes(42), "fused": axes(44)}}
    rows = [line for line in markdown(report) if line.startswith("| ") and "pairs scored" in line]
    assert len(rows) == 1 and "(42 of the 44 pairs scored)" in rows[0], rows


def test_the_report_says_why_pairs_were_left_out_of_a_rows_score():
    """"(70 of the 72 pairs scored)" said how many, not why: under the table, each such row's left-out
    pairs per axis and reason (no finite forecast, a measured force under 1 N); the figures unchanged."""
    from pinn_estimator.forecast import MIN_MEASURED_N, markdown, summarise

    def pair(measured, pinn):
        return {"soil": "Clay", "from_depth_m": 0.1, "to_depth_m": 0.2, "measured": measured, "intervals": {},
                "forecast": {"pinn": pinn, "true_fee": measured, "naive_same_force": measured}}

    pairs = [pair((1000.0, 500.0), (1100.0, 450.0)), pair((1000.0, 0.5), (float("nan"), float("nan"))),
             pair((800.0, 0.5 * MIN_MEASURED_N), (700.0, 10.0)), pair((900.0, 400.0), (990.0, 440.0))]
    forecast = summarise(pairs, ["pinn"])
    x = forecast["pinn"]["x"]["all"]
    assert (x["pairs"], x["no_finite_forecast"], x["measured_below_min"]) == (3, 1, 0)
    assert x["mean_abs_pct"] == (10.0 + 12.5 + 10.0) / 3  # the score over the pairs kept, as before
    z = forecast["pinn"]["z"]["all"]
    assert (z["pairs"], z["no_finite_forecast"], z["measured_below_min"]) == (2, 1, 1)
    lines = markdown({"data": "bags/x", "pairs": 4, "episodes": 4, "worlds": ["fee"], "unlabelled": 0,
                      "forecast": forecast})
    (note,) = [line for line in lines if line.startswith("Pairs left out")]
    assert ("PINN estimates (FEE part, β*): F_x: 1 with no finite forecast (no failure wedge); F_z: 1 with no finite "
            "forecast (no failure wedge), 1 with a measured force under 1 N.") in note, note
    assert "FEE with the true parameters: F_z: 2 with a measured force under 1 N." in note, note  # (F_x: every pair)


def test_a_path_that_goes_on_past_the_cut_is_one_soil_and_one_begun_past_its_first_patch_is_not(tmp_path):
    """A planned path longer than the cut (a second patch at 500 m): the episode is one soil where
    its edge went, and pairs (it had been left out as a soil change); a path whose first patch ends
    behind the edge's start is the second patch's soil, not its label's, and stays out."""
    from types import SimpleNamespace

    from pinn_estimator.forecast import episode_one_soil, one_soil

    far = ({"x_start_m": 0.0, "soil": "Sand", "relative_density_pct": 20.0},
           {"x_start_m": 500.0, "soil": "Clay", "relative_density_pct": 80.0})
    meta = SimpleNamespace(patches=far, soil="Sand", relative_density_pct=20.0)
    assert one_soil(meta, [2.0, 4.5]) and not one_soil(meta, [2.0, 501.0]) and not one_soil(meta)
    # a bag of before 2026-12-06, labelled after a first patch behind the edge: not its label's soil
    behind = ({"x_start_m": -3.0, "soil": "Sand", "relative_density_pct": 20.0},
              {"x_start_m": 1.0, "soil": "Clay", "relative_density_pct": 80.0})
    old_label = SimpleNamespace(patches=behind, soil="Sand", relative_density_pct=20.0)
    assert not one_soil(old_label, [2.0, 4.5]) and one_soil(old_label, [-1.0, 0.5])
    # labelled after the patch its edge starts in, as the simulator labels it now: one soil (a
    # reviewer's: such an episode had still been left out as a soil change)
    assert one_soil(SimpleNamespace(patches=behind, soil="Clay", relative_density_pct=80.0), [2.0, 4.5])
    alike = SimpleNamespace(patches=far[:1] + ({"x_start_m": 3.0, "soil": "Sand", "relative_density_pct": 20.0},) + far[1:],
                            soil="Sand", relative_density_pct=20.0)
    assert one_soil(alike, [2.0, 4.5]) and one_soil(SimpleNamespace(patches=()), None)

    specs = [EpisodeSpec("Sand", 20.0, 0.6, depth, seed=k, duration_s=5.0, patches=("0:Sand:20", "500:Clay:80"))
             for k, depth in enumerate((0.1, 0.2))]
    for ep in run_episodes(SimConfig(world_mode="fee"), specs):
        write_episode(tmp_path / "long" / ep.meta.name, ep)
    ds = load_dataset(tmp_path / "long", cache=False)
    assert all(episode_one_soil(ds, e) for e in range(len(ds)))
    start_beyond = EpisodeSpec("Loam", 50.0, 0.6, 0.15, seed=9, duration_s=5.0, patches=("0:Clay:80", "1:Sand:20"))
    ep = run_episodes(SimConfig(world_mode="fee"), [start_beyond])[0]
    write_episode(tmp_path / "beyond" / ep.meta.name, ep)
    assert episode_one_soil(load_dataset(tmp_path / "beyond", cache=False), 0)  # all Sand, its label, where its edge went
    parts = steady_parts(ds)
    assert len(list(pair_indices(parts))) == 2 and {p.soil for p in parts} == {"Sand"}


def test_bags_without_ground_truth_get_no_true_parameter_row_or_column():
    """A machine's bags have no truth: the true-parameter FEE's row was all dashes ("0 of the 8
    pairs scored") under a note saying there is none, and its per-soil column alike."""
    from pinn_estimator.forecast import LABELS, markdown

    def axes(pairs):
        row = {"pairs": pairs, "mean_abs_pct": 1.0, "bias_pct": 0.0}
        return {a: {"all": row, "deeper": row, "shallower": row} for a in ("x", "z")}

    def soil(pairs):
        cell = {"mean_abs_pct": 1.0, "bias_pct": 0.0}
        return {"pairs": pairs, **{n: {"x": cell, "deeper_x": cell} for n in ("fused", "true_fee", "naive_same_force")}}

    report = {"data": "bags/machine", "pairs": 8, "episodes": 8, "worlds": ["default"],
              "forecast": {"fused": axes(8), "true_fee": axes(0), "naive_same_force": axes(8)},
              "per_soil": {"Clay": soil(4), "Sand": soil(4)}, "parameters": {"fused": {}}}
    text = "\n".join(markdown(report))
    tables = "\n".join(line for line in text.splitlines() if line.startswith("|"))
    assert LABELS["true_fee"] not in tables and "there is no FEE with the true parameters" in text, text
    assert LABELS["naive_same_force"] in tables and "| Clay | 4 |" in tables
    with_truth = markdown({**report, "parameters": {"fused": {"phi": {"mae": 0.01, "episodes": 8, "coverage_90": 0.9, "coverage_50": 0.5}}}})
    # with truth its row is kept (0 pairs scored, said) and its per-soil column
    assert sum(LABELS["true_fee"] in line for line in with_truth if line.startswith("|")) == 2


def test_a_machines_bags_take_the_checkpoints_calibration_not_none(tmp_path, monkeypatch):
    """Bags whose world_mode is "unknown" (a machine's) took no calibration in the offline forecast:
    a posterior through the FEE alone, 41 % off with intervals holding 0 of the pairs, where the
    live estimator on the same bags runs the checkpoint world's (an outside tester's)."""
    from pinn_estimator.evaluate import forecast_section
    from pinn_estimator.fusion_calibration import load_calibrated

    specs = [EpisodeSpec("Clay", 20.0, 0.6, depth, seed=k, duration_s=5.0) for k, depth in enumerate((0.1, 0.2))]
    for ep in run_episodes(SimConfig(world_mode="default"), specs):
        write_episode(tmp_path / "machine" / ep.meta.name, ep)
    bags = load_dataset(tmp_path / "machine", cache=False)
    bags.metas = [replace(m, world_mode="unknown") for m in bags.metas]  # as a machine's bags say (the readers take it)
    said = []
    seen = {}

    def forecast(model, bags, *, fusion, **_):
        seen["fusion"] = fusion
        return {}

    monkeypatch.setattr("pinn_estimator.evaluate.forecast", forecast)  # (the forecast itself is tested elsewhere)
    out = forecast_section(None, bags, None, log=said.append, model_world="default")
    assert seen["fusion"] == load_calibrated("default") and seen["fusion"].terms, "the default world's, with its term"
    assert "no simulator world" in said[0] and "default world's calibration" in said[0], said
    assert "the checkpoint's" in out["fusion_config"] and "'unknown'" in out["fusion_config"], out


def test_the_fused_forecasts_outside_the_calibrated_depths_and_speed_are_scored_apart_and_said():
    """An outside tester's: a headline of 85 / 48 % hid 93 / 52 % at one speed and 79 / 45 % across
    speeds, and sources of 7 cm going deeper held 53 / 24 %; the report said neither. Calibrated
    means both depths among the cuts the calibration scores and both at its speed (a reviewer's:
    a pair to 10 cm, one beyond 0.3 m and two cuts at 1 m/s had counted as calibrated)."""
    import numpy as np

    from pinn_estimator.forecast import DEPTH_SLACK_M, FORECAST_SPEED_M_S, calibration_strata, markdown
    from pinn_estimator.fusion_calibration import CAL_DEPTHS_M, MIN_CALIBRATED_DEPTH_M, calibration_bounds

    reach = calibration_bounds()
    assert reach == (min(d for d in CAL_DEPTHS_M if d >= MIN_CALIBRATED_DEPTH_M), max(CAL_DEPTHS_M), FORECAST_SPEED_M_S)
    assert reach[:2] == (0.09, 0.3)

    def pair(d_from, d_to, v_from, v_to, forecast):  # measured 10 kN; the 90 % interval ± 1 kN about the forecast
        f = np.array([forecast, 0.0])
        return {"from_depth_m": d_from, "to_depth_m": d_to, "from_speed_m_s": v_from - 0.05, "to_speed_m_s": v_to - 0.05,
                "target_speeds_m_s": (v_from, v_to), "measured": np.array([10e3, 0.0]), "forecast": {"fused": f},
                "intervals": {"fused": {(0.05, 0.95): (f - 1e3, f + 1e3), (0.25, 0.75): (f - 300.0, f + 300.0)}}}

    v = FORECAST_SPEED_M_S
    pairs = [pair(0.15, 0.25, v, v, 10.2e3), pair(0.3 + DEPTH_SLACK_M / 2, 0.15, v, v, 9.9e3),  # calibrated: held
             pair(0.07, 0.2, v, v, 12e3), pair(0.15, 0.08, v, v, 12e3), pair(0.3, 0.4, v, v, 8e3),  # other depths
             pair(0.15, 0.25, 0.3, 1.0, 8e3), pair(0.15, 0.25, 1.0, 1.0, 8e3)]  # across speeds; one other speed
    strata = calibration_strata(pairs, ["fused"], reach)["posteriors"]["fused"]
    assert [strata[g]["pairs"] for g in ("calibrated", "other_depths", "across_speeds", "other_speed")] == [2, 3, 1, 1]
    assert strata["calibrated"]["coverage_90"] == 1.0 and strata["calibrated"]["coverage_50"] == 1.0
    assert strata["other_depths"]["coverage_90"] == 0.0 and strata["across_speeds"]["coverage_90"] == 0.0
    assert strata["other_depths"]["deeper_bias_pct"] == 0.0  # +20 % and −20 % going deeper (0.15 → 0.08 is not)
    row = {"pairs": 7, "mean_abs_pct": 1.0, "bias_pct": 0.0}
    report = {"data": "bags/x", "pairs": 7, "episodes": 7, "worlds": ["default"], "unlabelled": 0,
              "forecast": {"fused": {a: {"all": row, "deeper": row, "shallower": row} for a in ("x", "z")}},
              "calibration_strata": calibration_strata(pairs, ["fused"], reach)}
    text = "\n".join(markdown(report))
    assert (f"where its forecast law was calibrated (both depths 0.09–0.3 m, the cuts the calibration scores, both "
            f"cut at its {v:g} m/s): 2 pairs, 1.5 % off") in text
    assert "across speeds (steady speeds more than 0.1 m/s apart): 1 pair, 20.0 % off" in text
    inside = calibration_strata(pairs[:2], ["fused"], reach)  # every pair within it: nothing to say apart
    assert "the cuts the calibration scores" not in "\n".join(markdown({**report, "calibration_strata": inside}))


def test_the_fused_forecasts_within_the_planners_margin_and_beyond_it_are_scored_apart_and_said():
    """At the F_x limit the anti-stall controller lifts the blade, and the lift's push is in no soil
    model's F_z: held out, the F_z intervals held 87 / 56 % of the pairs within the planner's margin
    and 64 / 9 % beyond it, one figure of 83 / 49 % over both. A pair is judged by its forecast F_x
    (the median), which a user has without the measured force."""
    import numpy as np

    from pinn_estimator.forecast import margin_strata, markdown
    from soil_msgs_py.params import FORCE_LIMITS_N, PLANNER_FORCE_MARGIN
    from soil_planner.planner import DEFAULT_MARGIN

    assert DEFAULT_MARGIN == PLANNER_FORCE_MARGIN
    limit = PLANNER_FORCE_MARGIN * FORCE_LIMITS_N[0]

    def pair(fx, measured_fz, forecast_fz):  # F_x held; F_z's 90 % interval ± 1 kN, 50 % ± 300 N about its forecast
        f = np.array([fx, forecast_fz])
        return {"from_depth_m": 0.1, "to_depth_m": 0.2, "measured": np.array([fx * 1.01, measured_fz]),
                "forecast": {"fused": f},
                "intervals": {"fused": {(0.05, 0.95): (f - 1e3, f + 1e3), (0.25, 0.75): (f - 300.0, f + 300.0)}}}

    pairs = [pair(8e3, -500.0, -400.0), pair(limit - 1.0, 200.0, 0.0), pair(12e3, -900.0, -200.0),  # within: z held 3 / 2
             pair(limit, -6e3, 0.0), pair(19e3, -300.0, -200.0),  # beyond: z held 1 / 1 (the push is missed)
             {**pair(5e3, 0.0, 0.0), "forecast": {"fused": np.array([np.nan, np.nan])}}]  # no forecast: in neither
    strata = margin_strata(pairs, ["fused"])
    cells = strata["posteriors"]["fused"]
    assert strata["limit_n"] == limit and [cells[g]["x"]["pairs"] for g in ("within", "beyond")] == [3, 2]
    assert (cells["within"]["z"]["coverage_90"], cells["within"]["z"]["coverage_50"]) == (1.0, 2 / 3)
    assert (cells["beyond"]["z"]["coverage_90"], cells["beyond"]["z"]["coverage_50"]) == (0.5, 0.5)
    row = {"pairs": 5, "mean_abs_pct": 1.0, "bias_pct": 0.0}
    report = {"data": "bags/x", "pairs": 5, "episodes": 5, "worlds": ["default"], "unlabelled": 0,
              "forecast": {"fused": {a: {"all": row, "deeper": row, "shallower": row} for a in ("x", "z")}},
              "margin_strata": strata}
    text = "\n".join(markdown(report))
    assert (f"(median) is within the planner's margin ({PLANNER_FORCE_MARGIN:g} of the limit, below {limit / 1e3:g} "
            "kN: about the cuts a planner plans, which keeps the 95 % bound within it): 3 pairs, F_x held in 100% / "
            "100%, F_z in 100% / 67%; beyond it: 2 pairs, F_x held in 100% / 100%, F_z in 50% / 50%") in text
    within_only = margin_strata(pairs[:3], ["fused"])  # none beyond: nothing to say apart
    assert "the planner's margin" not in "\n".join(markdown({**report, "margin_strata": within_only}))
