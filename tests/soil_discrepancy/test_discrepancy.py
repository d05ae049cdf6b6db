"""The discrepancy workflow: hidden effects are found, named, fitted and shown to help
on held-out episodes; the control data give none; nothing reads ground truth.

Three small fee-world datasets are generated into a temporary directory (4 soils x I_d {20, 80}
x speed {0.3, 1.0} m/s x depth {0.1, 0.25} m, 10 s episodes — the grid of bags/disc/): control,
soil_inertia k = 4 and compaction_hardening k = 0.06 switched on in the simulator through the
catalogue's own plugin.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pinn_estimator.dataset import Dataset, fingerprint_bags, load_dataset
from soil_bag_tools.bag_io import find_episode_bags
from soil_discrepancy import (
    build_frame,
    compare_predictions,
    group_folds,
    holm,
    regime_analysis,
    run_discrepancy,
    split_holdout,
)
from soil_discrepancy.cli import main as cli_main
from soil_discrepancy.gap import depth_forecast_gap
from soil_discrepancy.workflow import _grouping
from soil_msgs_py import cli_numbers
from soil_physics import force_terms, fee
from soil_physics.augmented_fee import AugmentedFEE
from soil_physics.force_inputs import ForceInputs
from soil_msgs_py.params import KNOWN_PARAMS
from soil_physics.soils import CATALOGUE as SOILS
from soil_sim_node.batch import DatasetPlan, generate, grid_specs
from soil_sim_node.effects import effects_for_mode, load_plugins
from soil_sim_node.rollout import run_episodes

HIDDEN = {
    "control": (),
    "soil_inertia": ("soil_physics.force_terms:plugin term=soil_inertia k=4",),
    "compaction": ("soil_physics.force_terms:plugin term=compaction_hardening k=0.06",),
}
RUN = dict(holdout=0.3, folds=5, seed=0, stride=6, workers=2, log=None)


def small_grid() -> list:
    """The hidden-effect tests' 32 fee-world episodes: 4 soils × I_d 20 / 80 % × 0.3 / 1 m/s ×
    0.1 / 0.25 m, one 10 s episode each, seeds from 0."""
    return grid_specs(list(SOILS), [20.0, 80.0], [0.3, 1.0], [0.1, 0.25], 1, seed_base=0, duration_s=10.0)


def named_verdict(rep: dict) -> str:
    """The verdict a report that names terms must carry: "partly explained" where the residual keeps
    significant structure beside them, where every term named is a form its data do not pin down
    and together they take less than a quarter off the held-out error, where they make one axis
    worse on the held-out episodes, where they leave θ on the soil tests' bounds in more groups
    than chance explains, or where the soil fitted beside them lies outside its label's textbook
    range in a group cut at more than one depth; else "explained"."""
    from soil_discrepancy.forms import pin_kind
    from soil_discrepancy.verdict import STAND_IN_MAX_GAIN, WEAK_PIN_KINDS, _worse_axes, bound_hits_by_chance

    after_reg = rep.get("regimes_after") or {}
    if after_reg.get("significant"):
        return "partly explained"
    if rep.get("test") and rep["test"].get("after") and _worse_axes(rep["test"]):
        return "partly explained"
    if after_reg.get("misfit") and bound_hits_by_chance(after_reg) < after_reg["misfit"]["alpha"]:
        return "partly explained"
    if any(r["kind"] == "group" and r.get("theta_off_label") and not r.get("one_depth")
           for r in (after_reg.get("misfit") or {}).get("rows", [])):
        return "partly explained"
    pins = {d["name"]: d.get("pin") for d in ((rep.get("forms") or {}).get("discovered") or [])}
    named = [a["name"] for a in rep["selection"]["accepted"]]
    before, after = (rep.get("test") or {}).get("before", {}).get("rmse"), (rep.get("test") or {}).get("after", {}).get("rmse")
    weak = (named and before and after is not None and 1 - after / before < STAND_IN_MAX_GAIN
            and all(pin_kind(pins.get(n)) in WEAK_PIN_KINDS for n in named))
    return "partly explained" if weak else "explained"


@pytest.fixture(scope="module")
def bag_dirs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("disc")
    out = {}
    for name, plugins in HIDDEN.items():
        plan = DatasetPlan("fee", root / name, small_grid(), effects_for_mode("fee"), plugins=plugins)
        generate(plan, workers=2, progress=False)
        out[name] = root / name
    return out


class _Forbidden:
    """Stands in for Dataset.truth: any use fails the test."""

    def _fail(self, *_, **__):
        raise AssertionError("the discrepancy analysis read the ground truth (Dataset.truth)")

    __getitem__ = __array__ = __len__ = __iter__ = _fail

    def __getattr__(self, name):
        self._fail()


def blind(bag_dir: Path):
    """The dataset as a real machine would give it: no ground truth, no record of the simulator's effects.

    Read through the dataset cache (keyed by the bags' bytes, as the CLI reads them): a module's
    tests read one directory many times, and reading its bags costs seconds each time."""
    return _blinded(load_dataset(bag_dir, workers=2))


def _blinded(ds):
    metas = [dataclasses.replace(m, plugins=[], effects=[]) for m in ds.metas]
    return dataclasses.replace(ds, truth=_Forbidden(), metas=metas)


def simulated(specs, plugins=(), mode: str = "fee", effects=None):
    """``blind`` of the bags ``generate`` would write for ``specs`` with the hidden ``plugins``,
    simulated here in one vectorised batch, no bags written or read (a seventh of the time; the
    bag path itself is what the CLI tests and test_simulated_equals_the_bags_read_back use).
    Episodes in the bags' order (by name), as the analysis's groups and folds depend on it."""
    plan = DatasetPlan(mode, Path("(in memory)"), specs, effects or effects_for_mode(mode), plugins=tuple(plugins))
    episodes = sorted(run_episodes(plan.config(), specs), key=lambda ep: ep.meta.name)
    return _blinded(Dataset.from_episodes(episodes))


HOOK_CALLS: list = []


def fake_pinn(test_frame, model_before, model_after, context):
    """Stands in for the PINN comparison another engineer adds: records what the hook gives it."""
    HOOK_CALLS.append((test_frame, model_before, model_after, context))
    return test_frame.forces + 1000.0, test_frame.forces + 100.0


@pytest.fixture(scope="module")
def reports(bag_dirs, tmp_path_factory) -> dict[str, dict]:
    out = {}
    for name in ("soil_inertia", "compaction"):
        hook = {"fake PINN": fake_pinn} if name == "soil_inertia" else None
        out[name] = run_discrepancy(dataset=blind(bag_dirs[name]), out_dir=tmp_path_factory.mktemp(name),
                                    predictors=hook, plots=name == "soil_inertia", **RUN)  # test_report_files reads its PNGs
    return out


@pytest.mark.parametrize("name", sorted(HIDDEN))
def test_simulated_equals_the_bags_read_back(bag_dirs, name):
    """The hidden-effect tests that do not test the bag path take their data from ``simulated``:
    it must be what the bags of ``generate`` read back give, episode for episode and to the bit."""
    got, want = simulated(small_grid(), HIDDEN[name]), blind(bag_dirs[name])
    assert got.names == want.names and got.metas == want.metas
    np.testing.assert_array_equal(got.offsets, want.offsets)
    for field in ("observations", "forces", "known", "gap_before"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
    with pytest.raises(AssertionError, match="ground truth"):
        got.truth[0]


# ------------------------------------------------------------------------------ the hidden effects
@pytest.mark.parametrize("name, term, k_true", [("soil_inertia", "soil_inertia", 4.0),
                                                 ("compaction", "compaction_hardening", 0.06)])
def test_hidden_effect_is_named_fitted_and_halves_the_heldout_error(reports, name, term, k_true):
    rep = reports[name]
    assert rep["verdict"] == "explained", rep["summary"]
    accepted = rep["selection"]["accepted"]
    assert [a["name"] for a in accepted] == [term], "exactly the hidden effect, nothing invented on top"
    a = accepted[0]
    assert a["k"] == pytest.approx(k_true, rel=0.25)
    assert a["p_holm"] < 0.01 and a["gain"] >= 0.5 and a["k_se"] < 0.1 * a["k"]
    if term == "soil_inertia":
        # its v_x² is not pinned down on two speeds, where any factor of speed matches it (k and θ
        # take the rest): it was called "pinned down", the forms that were its own column here
        # (v_x, v_x², tanh(v_x / 1 m/s)) listed as saying the same thing
        few = a["pin"]["few_levels"]
        assert not a["pin"]["pinned"] and few["variable"] == "v_x" and len(few["levels"]) == 2, a["pin"]
        assert "its form is NOT pinned down" in rep["summary"] and "v_x takes values in only 2 group(s)" in rep["summary"]
    else:  # pinned down: no form of the library fits what it takes as well
        assert a["pin"]["pinned"] and "pinned down" not in rep["summary"], a["pin"]
    # asked on both parts: the held-out one (8 episodes, where two against the term would keep a
    # one-sided Wilcoxon above α) is too small to judge, and the report says so
    assert a["pin"]["judged_on"] == ["selection"] and a["pin"]["part"] == "selection", a["pin"]
    assert [f["part"] for f in a["pin"]["too_few"]] == ["held-out test"], a["pin"]
    md = (Path(rep["outputs"][0]).parent / "discrepancy.md").read_text()
    assert "(The held-out test part, 8 episodes, too few" in md
    test = rep["test"]
    assert test["after"]["rmse"] <= 0.5 * test["before"]["rmse"], (test["before"], test["after"])
    assert test["after"]["rmse_x"] < test["before"]["rmse_x"]
    # the held-out test episodes were never used for the selection
    assert not set(rep["data"]["test_episodes"]) & set(rep["data"]["selection_episodes"])
    # the model and the simulator side of the accepted term
    assert rep["model"]["plugin_specs"] == [f"soil_physics.force_terms:plugin term={term} k={a['k']:.6g}"]
    assert load_plugins(rep["model"]["plugin_specs"])[0].params == {"term": term, "k": pytest.approx(a["k"], rel=1e-5)}
    assert rep["regimes"]["significant"], "the baseline residual shows where the model is wrong"


def _not_strict(constant):
    raise ValueError(f"not strict JSON (JSON.parse refuses it): {constant}")


def test_report_files(reports, bag_dirs):
    rep = reports["soil_inertia"]
    out = Path(rep["outputs"][0]).parent
    for f in ("discrepancy.json", "discrepancy.md", "residuals_by_regime.png", "heldout_gap.png", "candidates.png"):
        assert (out / f).stat().st_size > 0, f
    saved = json.loads((out / "discrepancy.json").read_text(), parse_constant=_not_strict)  # strict JSON
    assert saved["verdict"] == "explained" and saved["model"]["terms"][0][0] == "soil_inertia"
    md = (out / "discrepancy.md").read_text()
    assert "soil_physics.force_terms:plugin term=soil_inertia" in md and "Held-out test episodes" in md
    # the soil per group with the named term, beside the baseline's (a term and θ can trade off)
    assert [t["group"] for t in saved["model"]["theta"]] == [t["group"] for t in saved["baseline"]["theta"]]
    assert set(saved["model"]["theta_shift"]) == {"phi_deg", "c_pa", "delta_deg"}
    assert "| with the named terms: φ [°] / c [Pa] / δ [°] |" in md and "With the named terms the fitted soil moves by" in md
    # what it was computed from: the bags' content fingerprint and the software that ran it
    fingerprint = saved["data"]["fingerprint"]
    assert fingerprint == fingerprint_bags(find_episode_bags(bag_dirs["soil_inertia"]), bag_dirs["soil_inertia"])
    assert f"content fingerprint `{fingerprint[:16]}`" in md
    assert saved["environment"]["numpy"] == np.__version__ and f"numpy {np.__version__}" in md


def test_a_soil_the_named_terms_move_far_is_said_in_the_verdict():
    """Beside a term that trades off with θ (a relief fading with speed fitted with φ 29° higher;
    a rate law whose offset became a cohesion of 1.4 kPa in sand) the force fits with another soil:
    the verdict says so, with the parameter, the move and the group, where a move is larger than a
    soil test's interval would allow; smaller moves, and no named terms, say nothing."""
    from soil_discrepancy.verdict import theta_shift_text, theta_shift

    before = [{"group": "Clay I_d=0%", "phi_deg": 16.5, "c_pa": 5000.0, "delta_deg": 14.9},
              {"group": "Sand I_d=40%", "phi_deg": 35.0, "c_pa": 20.0, "delta_deg": 14.9}]
    after = [{"group": "Clay I_d=0%", "phi_deg": 45.5, "c_pa": 4000.0, "delta_deg": 15.0},
             {"group": "Sand I_d=40%", "phi_deg": 36.0, "c_pa": 1420.0, "delta_deg": 14.9}]
    shift = theta_shift(before, after)
    assert shift["phi_deg"]["largest"] == pytest.approx(29.0) and shift["phi_deg"]["group"] == "Clay I_d=0%"
    assert shift["c_pa"]["largest"] == pytest.approx(1400.0) and shift["c_pa"]["group"] == "Sand I_d=40%"
    text = theta_shift_text(shift)
    assert "φ +29.0° in Clay I_d=0%" in text and "c +1.40 kPa in Sand I_d=40%" in text and "δ" not in text, text
    assert "--soil-tests" in text and "fit box" not in text
    # where θ leaves its fit box with the terms (the baseline's θ took the effect in: soil inertia's dense
    # loam at φ 5°), or reaches it (the terms take part of the soil), the group says so
    reg = lambda *groups: {"misfit": {"rows": [{"kind": "group", "name": g, "theta_at_bound": ["φ at its lower bound"]}
                                               for g in groups]}}
    released = theta_shift_text(shift, reg("Clay I_d=0%", "Loam I_d=80%"), reg("Sand I_d=40%"))
    doubt, support = released.split("; in other groups the soil fitted beside them leaves the fit box the baseline's sat on")
    assert doubt.startswith("; in some groups the soil fitted beside them is another"), released
    assert "c +1.40 kPa in Sand I_d=40%, onto its fit box with them" in doubt and "φ" not in doubt, released
    assert "φ +29.0° in Clay I_d=0%" in support and "speaks for them" in support and "c " not in support, released
    # the terms leave θ on the box in more than half the groups it sat on (the default world: 11, then
    # 9): a group leaving it is no sign, only tagged
    tagged = theta_shift_text(shift, reg("Clay I_d=0%"), reg("Sand I_d=40%"))
    assert "leaves the fit box" not in tagged and "φ +29.0° in Clay I_d=0%, off its fit box with them" in tagged, tagged
    assert "c +1.40 kPa in Sand I_d=40%, onto its fit box with them" in tagged, tagged
    # every move leaving the box: no word of another soil (a tip penetration hidden on another grid
    # was named with the baseline's θ on its box and the clay's φ back near the truth)
    freed = theta_shift_text(shift, reg("Clay I_d=0%", "Sand I_d=40%"), reg())
    assert "is another" not in freed and "φ +29.0° in Clay I_d=0%; c +1.40 kPa in Sand I_d=40%" in freed, freed
    assert freed.startswith("; the soil fitted beside them leaves the fit box"), freed
    small = theta_shift(before, [{**r, "phi_deg": r["phi_deg"] + 2.0, "c_pa": r["c_pa"] + 500.0} for r in before])
    assert theta_shift_text(small) == "" and theta_shift(before, None) is None and theta_shift_text(None) == ""



@pytest.mark.parametrize("signal_name, code", [("Ctrl-C", 130), ("SIGTERM", 143)])
def test_ctrl_c_or_sigterm_while_pinns_train_says_so_in_one_line_and_writes_no_report(bag_dirs, tmp_path, capsys,
                                                                                    monkeypatch, signal_name, code):
    """Ctrl-C (or SIGTERM) while the PINNs train: the run printed its KeyboardInterrupt traceback
    (and its workers theirs) and exited -2. Now one line, 130 / 143, no report; the workers ignore
    Ctrl-C and die on SIGTERM (tests/soil_msgs_py/test_map_in_processes.py)."""
    from soil_discrepancy import pinn_check
    from soil_msgs_py.interrupts import Terminated

    def interrupted(*args, **kwargs):
        raise Terminated() if signal_name == "SIGTERM" else KeyboardInterrupt()

    monkeypatch.setattr(pinn_check, "pinn_gap", interrupted)
    out = tmp_path / "out"
    assert cli_main([str(bag_dirs["soil_inertia"]), "--out", str(out), "--stride", "12", "--no-forms", "--no-plots",
                     "--workers", "2", "--pinn-epochs", "2", "--quiet"]) == code
    err = capsys.readouterr().err
    assert err == f"soil_discrepancy: interrupted ({signal_name}); no report written\n", err
    assert not (out / "discrepancy.json").exists()


def test_a_stop_while_the_pinn_step_is_made_ready_is_said_too(bag_dirs, tmp_path, capsys, monkeypatch):
    """Most of a short run is before the analysis (the PINN step's torch import, the arguments'
    checks), where the stop handling did not reach: a Ctrl-C there was a traceback, a SIGTERM a
    silent death (an outside tester's, 11 of 15). The whole run is covered now."""
    from soil_discrepancy import cli

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt()

    monkeypatch.setattr(cli, "_pinn_predictor", interrupted)
    out = tmp_path / "out"
    assert cli_main([str(bag_dirs["soil_inertia"]), "--out", str(out), "--pinn-epochs", "2", "--quiet"]) == 130
    assert capsys.readouterr().err == "soil_discrepancy: interrupted (Ctrl-C); no report written\n"


def test_control_gives_no_effect_through_the_cli_from_a_simulators_and_a_machines_bags(bag_dirs, tmp_path, capsys):
    """The control's answer, with the PINN's retraining asked for (nothing named: skipped) and the
    hidden check (none hidden: correct); and from the same bags recorded without
    /soil/ground_truth, as a machine records them (the analysis never uses it), the same answer to
    the figure."""
    from soil_bag_tools.bag_io import read_episode, write_episode

    machine = tmp_path / "machine"
    for bag in find_episode_bags(bag_dirs["control"]):
        write_episode(machine / bag.name, read_episode(bag), ground_truth=False)
    assert not read_episode(next(iter(find_episode_bags(machine)))).has_ground_truth
    reps = {}
    for name, bags in (("control", bag_dirs["control"]), ("machine", machine)):
        assert cli_main([str(bags), "--out", str(tmp_path / name), "--stride", "12", "--workers", "2", "--quiet",
                         "--no-plots", "--pinn-epochs", "4", "--hidden", "none"]) == 0
        reps[name] = json.loads((tmp_path / name / "discrepancy.json").read_text(), parse_constant=_not_strict)
    rep = reps["control"]
    assert rep["hidden_check"]["correct"] and "skipped" in rep["test"]["predictors"]["PINN"]
    assert rep["selection"]["accepted"] == [] and rep["model"]["terms"] == []
    assert rep["verdict"] == "no significant discrepancy", rep["summary"]
    assert all(not s["accepted"] and (s["gain"] is None or s["gain"] < 0.05) for s in rep["selection"]["rounds"][0]["scores"])
    assert "verdict: no significant discrepancy" in capsys.readouterr().out
    assert reps["machine"]["verdict"] == rep["verdict"] and reps["machine"]["test"] == rep["test"]
    assert reps["machine"]["data"]["world"] == rep["data"]["world"] == "fee"


# ------------------------------------------------------------------------------ bad input
def test_cli_bad_input_exits_2_naming_the_problem(bag_dirs, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli_main([str(empty), "--out", str(tmp_path / "o")]) == 2
    assert "no episode bags" in capsys.readouterr().err
    assert cli_main([str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert cli_main([str(bag_dirs["control"]), "--out", str(tmp_path / "o"), "--terms", "magic"]) == 2
    assert "magic" in capsys.readouterr().err
    assert cli_main([str(bag_dirs["control"]), "--out", str(tmp_path / "o"), "--pinn-epochs", "2", "--pinn-seeds", "0"]) == 2
    assert "--pinn-seeds 0 must be >= 1" in capsys.readouterr().err
    # the run's own settings are refused before any bag is read (a missing directory is not reached)
    for flag, value, said in (("--holdout", "1.5", "holdout=1.5 must be in (0, 1)"),
                              ("--holdout", "0", "holdout=0.0 must be in (0, 1): the held-out soil groups are what confirms"),
                              ("--stride", "0", "stride=0 must be an integer in [1, 60] ticks"),
                              ("--stride", "100000", "stride=100000 must be an integer in [1, 60] ticks")):
        assert cli_main([str(tmp_path / "missing"), "--out", str(tmp_path / "o"), flag, value]) == 2
        err = capsys.readouterr().err
        assert said in err and "not a directory" not in err, err
    # a bag without the force topic
    from rosbags.rosbag2 import StoragePlugin, Writer

    from soil_msgs_py import messages
    from soil_bag_tools.bag_io import META_KEY, find_episode_bags, read_episode
    from soil_msgs_py.messages import TYPESTORE
    from soil_msgs_py.topics import EPISODE_TOPICS

    ep = read_episode(find_episode_bags(bag_dirs["control"])[0])
    bad = tmp_path / "noforce" / "ep"
    bad.parent.mkdir()
    with Writer(bad, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        w.set_custom_data(META_KEY, ep.meta.to_json())
        conns = {t.name: w.add_connection(t.name, t.msgtype, typestore=TYPESTORE)
                 for t in EPISODE_TOPICS if t.name != "/blade/force"}
        for topic, stamp, raw in messages.serialize_episode(ep):
            if topic in conns:
                w.write(conns[topic], stamp, raw)
    assert cli_main([str(bad.parent), "--out", str(tmp_path / "o"), "--no-cache"]) == 2
    assert "/blade/force" in capsys.readouterr().err


def test_the_hidden_check_with_two_effects_hidden_at_once_says_which_were_named():
    """``--hidden A=K,B=K`` (test data only): correct when the first term named is one of them, each
    said found (with its k) or not; one hidden effect keeps its one-line check."""
    from soil_discrepancy.cli import hidden_check

    def report(*named):
        return {"selection": {"accepted": [{"name": n, "k": k} for n, k in named]},
                "test": {"before": {"rmse": 1597.0}, "after": {"rmse": 578.0}}}

    both = [("soil_inertia", 3.0), ("compaction_hardening", 0.05)]
    check = hidden_check(report(("compaction_hardening", 0.068), ("soil_inertia", 2.88)), both)
    assert check["correct"] and check["hidden_all"] == [list(h) for h in both] and check["hidden"] == ["soil_inertia", 3.0]
    assert "soil_inertia (k = 3) hidden, named with k = 2.88; compaction_hardening (k = 0.05) hidden, named with k = 0.068" in check["text"]
    mimic = hidden_check(report(("form:mom_x*tsat3", 5.73)), both)
    assert not mimic["correct"] and mimic["text"].count("not named") == 2 and ": WRONG" in mimic["text"]
    one = hidden_check(report(("soil_inertia", 2.88)), both[:1])
    assert one["correct"] and one["text"].startswith("soil_inertia (k = 3) hidden; named ['soil_inertia'] with k = 2.88: correct")
    assert hidden_check(report(), None)["text"].startswith("none hidden; none named: correct")
    # the default world lacks physics of its own: a form named instead of the hidden effect is not called wrong
    in_default = {**report(("form:q_z*sink", 0.89)), "data": {"world": "default"}}
    sink = hidden_check(in_default, both[:1])
    assert not sink["correct"] and "WRONG" not in sink["text"] and ": not named (the default world has effects" in sink["text"]
    second = hidden_check({**report(("form:q_z*sink", 0.89), ("soil_inertia", 3.4)), "data": {"world": "default"}}, both[:1])
    assert not second["correct"] and ": soil_inertia named, not first (the default world" in second["text"]
    assert ": WRONG" in hidden_check({**report(("form:q_z*sink", 0.89)), "data": {"world": "fee"}}, both[:1])["text"]
    # nothing named (unexplained, or no discrepancy found) is a miss, not a wrong name
    missed = hidden_check(report(), both[:1])
    assert not missed["correct"] and "WRONG" not in missed["text"] and "named none: missed (nothing named)" in missed["text"]
    # a hidden term that never acted (surcharge_drag where Q = 0: its basis 0 on every tick, the
    # workflow's first round says so) hides nothing: the data are a control, not a miss
    from soil_discrepancy.candidates import ZERO_BASIS_NOTE

    idle = {**report(), "selection": {"accepted": [], "rounds": [{"scores": [
        {"name": "surcharge_drag", "note": ZERO_BASIS_NOTE}]}]}}
    none_there = hidden_check(idle, [("surcharge_drag", 0.3)])
    assert none_there["correct"] and "missed" not in none_there["text"], none_there
    assert "surcharge_drag (k = 0.3) hidden, but it never acted on these data" in none_there["text"]
    assert none_there["text"].split("; held-out")[0].endswith("named none: correct")
    # a named term whose own column on these data the hidden one is (two speeds: w d tanh(v_x / 1 m/s) is
    # rate strength's w d v_x there) was "WRONG" though the report listed it as the same statement
    same = {**report(("rate_strength", 7000.0)), "data": {"world": "fee"}}
    same["selection"]["accepted"][0]["pin"] = {"same_column": ["form:wd_x*vx2", "form:wd_x*tanhvx1"]}
    check = hidden_check(same, [("form:wd_x*tanhvx1", 1.5)])
    assert check["correct"] and "WRONG" not in check["text"], check
    assert "correct, rate_strength being form:wd_x*tanhvx1's own column on these data" in check["text"]
    assert ": WRONG" in hidden_check(same, [("form:wd_x*fadevx1", 1.5)])["text"]
    idle["selection"]["accepted"] = [{"name": "soil_inertia", "k": 2.0}]
    assert ": WRONG" in hidden_check(idle, [("surcharge_drag", 0.3)])["text"]
    assert ", never acted on these data" in hidden_check(idle, [("surcharge_drag", 0.3), ("soil_inertia", 2.0)])["text"]


def test_repeated_accepted_terms_bad_workers_and_seeds_are_refused_naming_the_option(tmp_path, capsys):
    """--accepted soil_inertia=1,soil_inertia=2 summed silently to k = 3 (pinn_train refuses the
    same); --workers -1 was taken as 1 and --seed -1 failed in numpy's words ("expected non-negative
    integer") after the bags were read. All refused before any bag is read, naming the option."""
    missing = str(tmp_path / "missing")
    assert cli_main([missing, "--out", str(tmp_path / "o"), "--accepted", "soil_inertia=1,soil_inertia=2"]) == 2
    err = capsys.readouterr().err
    assert "--accepted: effect term soil_inertia is given more than once" in err and "not a directory" not in err, err
    # a negative k is said (an outside tester's soil_inertia=-1 on clean data made the search name a stand-in undoing it)
    assert cli_main([missing, "--out", str(tmp_path / "o"), "--accepted", "soil_inertia=-1"]) == 2  # (no bags)
    assert "warning: --accepted soil_inertia=-1: a negative k turns the term against its mechanism" in capsys.readouterr().err
    most = cli_numbers.local_limit()  # more processes than 8 per core only wait (and forked without bound)
    for flag, value, said in (("--workers", "-1", f"argument --workers: '-1' must be an integer in [0, {most}]"),
                              ("--workers", str(most + 1), f"argument --workers: '{most + 1}' must be an integer in [0, {most}]"),
                              ("--seed", "-1", "argument --seed: '-1' must be an integer in [0, 2**32 - 1]")):
        with pytest.raises(SystemExit) as exit_:
            cli_main([missing, "--out", str(tmp_path / "o"), flag, value])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and said in err, err
    # 0: one process per core, as soil_sim_batch --workers 0 (the tools disagreed)
    assert cli_numbers.workers("0") == len(os.sched_getaffinity(0)) and cli_numbers.workers("1") == 1
    assert cli_main([missing, "--out", str(tmp_path / "o"), "--hidden", "soil_inertia=3,soil_inertia=2"]) == 2
    err = capsys.readouterr().err
    assert "--hidden: effect term soil_inertia is given more than once" in err and "not a directory" not in err, err
    # the top seed is one, but the retrained PINNs take one seed each from it: refused now, not after the analysis
    assert cli_main([missing, "--out", str(tmp_path / "o"), "--seed", str(2**32 - 1), "--pinn-epochs", "1",
                     "--pinn-seeds", "2"]) == 2
    err = capsys.readouterr().err
    assert "--seed 4294967295 with --pinn-seeds 2 seeds PINNs beyond 2**32 - 1" in err and "not a directory" not in err, err


def test_an_accepted_k_that_overflows_the_model_is_refused_naming_it(tmp_path, capsys):
    """soil_inertia=1e200 makes the baseline force overflow: the run ended in a TypeError formatting
    the RMS (None); at 1e150 it reported 2e152 N of residual. Now exit 2 naming the term and its k,
    and no report is written."""
    from tests.tiny_data import write_tiny_bags

    bags = write_tiny_bags(tmp_path / "bags")
    for k in ("1e200", "1e150"):
        out = tmp_path / f"o{k}"
        assert cli_main([str(bags), "--out", str(out), "--accepted", f"soil_inertia={k}", "--workers", "1",
                         "--no-plots", "--no-cache", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "is not a finite force of at most 9e+06 N with the accepted term(s) soil_inertia=" in err, err
        assert not (out / "discrepancy.json").exists()


# ------------------------------------------------------------------------------ the pieces
def test_augmented_fee_is_the_fee_plus_the_catalogue_terms(bag_dirs):
    ds = load_dataset(bag_dirs["control"])
    known = ds.known[ds.known[:, KNOWN_PARAMS.index("d")] > 0.05][:50]
    theta = (np.full(len(known), 0.5), np.full(len(known), 3e3), np.full(len(known), 0.25))
    dist = np.linspace(0.0, 3.0, len(known))
    model = AugmentedFEE(["soil_inertia=2", ("compaction_hardening", 0.05)])
    fx, fz = model.force(theta, known, dist)
    f0 = {n: known[:, i] for i, n in enumerate(KNOWN_PARAMS)}
    f0.update(phi=theta[0], c=theta[1], delta=theta[2])
    gx, gz, _ = fee.fee_xz(f0)
    inputs = ForceInputs(**{n: f0[n] for n in ("d", "q", "v_x", "v_z", "gamma", "w", "rho", "alpha", "phi", "c", "delta")},
                         distance_in_soil=dist, f_fee_x=gx, f_fee_z=gz)
    dx, dz = force_terms.apply(model.terms, inputs)
    np.testing.assert_allclose(fx, gx + dx, rtol=1e-12)
    np.testing.assert_allclose(fz, gz + dz, rtol=1e-12)
    assert model.with_term("soil_inertia", 3.0).terms == (("compaction_hardening", 0.05), ("soil_inertia", 3.0))
    assert model.extra_term_args() == ["soil_inertia=2", "compaction_hardening=0.05"]
    with pytest.raises(ValueError, match="not one of"):
        AugmentedFEE(["nope=1"])


def test_regime_tests_flag_a_planted_bias_but_not_noise(bag_dirs):
    frame = build_frame(load_dataset(bag_dirs["control"]), stride=4)
    rng = np.random.default_rng(0)
    fmag = np.hypot(frame.forces[:, 0], frame.forces[:, 1])
    ep_offset = rng.normal(0.0, 0.01, len(frame.names))[frame.episode] * fmag
    noise = np.stack([ep_offset + rng.normal(0, 300, len(frame)), rng.normal(0, 300, len(frame))], 1)
    quiet = regime_analysis(frame, noise)
    assert not quiet["significant"], [r for r in quiet["bins"] + quiet["trends"] if r["flagged"]]
    planted = noise.copy()
    fast = frame.column("v_x") > 0.6
    planted[fast, 0] += 0.08 * fmag[fast]  # fast episodes push 8 % harder than the model
    loud = regime_analysis(frame, planted)
    assert "v_x" in loud["flagged_variables"]
    assert any(r["flagged"] and r["variable"] == "v_x" and r["axis"] == "x" for r in loud["bins"])


def test_holm_matches_the_definition():
    p = np.array([0.01, 0.04, 0.03, np.nan, 0.005])
    np.testing.assert_allclose(holm(p)[[4, 0, 2, 1]], [0.02, 0.03, 0.06, 0.06])
    assert np.isnan(holm(p)[3])


def test_splits_are_by_group_stratified_and_folds_partition(bag_dirs):
    frame = build_frame(load_dataset(bag_dirs["control"]), stride=4)
    assert len(frame.groups) == 8 and frame.group_names[0].startswith("Clay I_d=20")
    sel, test = split_holdout(frame, 0.3, seed=0)
    assert len(test) == 2 and not set(sel) & set(test) and len(sel) + len(test) == 8
    soils = {frame.group_names[g].split()[0] for g in test}
    assert len(soils) == 2, "the test part spans soils"
    assert split_holdout(frame, 0.3, seed=0) == (sel, test)
    folds = group_folds(sel, 5, seed=0)
    held = sorted(g for _, h in folds for g in h)
    assert held == sorted(sel) and all(not set(tr) & set(h) for tr, h in folds)
    per_episode = build_frame(load_dataset(bag_dirs["control"]), stride=4, group_by="episode")
    assert len(per_episode.groups) == len(per_episode.names) == 32


def test_episodes_whose_soil_changes_along_the_path_are_left_out_and_named(bag_dirs):
    """One θ cannot hold across a soil change (a fit across it reads the change as missing physics):
    episodes whose metadata lists patches of two soils are left out and named; patches of one soil
    are one soil; a dataset of nothing else is refused with the reason."""
    ds = load_dataset(bag_dirs["control"])
    two = [{"x_start_m": 0.0, "soil": "Sand", "relative_density_pct": 20.0},
           {"x_start_m": 2.5, "soil": "Clay", "relative_density_pct": 90.0}]  # the edge starts at 2 m: every cut crosses 2.5 m
    same = [dict(two[0]), {**two[0], "x_start_m": 2.5}]

    def patched(m, patches):  # labelled after the patch its edge starts in, as the simulator labels it
        return dataclasses.replace(m, patches=patches, soil=patches[0]["soil"],
                                   relative_density_pct=patches[0]["relative_density_pct"])

    metas = [patched(m, two) if i < 3 else patched(m, same) if i == 3 else m for i, m in enumerate(ds.metas)]
    full = build_frame(ds, stride=4)
    frame = build_frame(dataclasses.replace(ds, metas=metas), stride=4)
    assert frame.changing_soil == tuple(ds.names[:3])
    assert set(frame.episodes) == set(full.episodes) - {0, 1, 2} and 3 in set(frame.episodes)
    assert not full.changing_soil
    beyond = [dict(two[0]), {**two[1], "x_start_m": 500.0}]  # a path going on past every cut: one soil where the edge went
    assert not build_frame(dataclasses.replace(ds, metas=[patched(m, beyond) for m in ds.metas]), stride=4).changing_soil
    with pytest.raises(ValueError, match="changes soil along its path"):
        build_frame(dataclasses.replace(ds, metas=[patched(m, two) for m in ds.metas]), stride=4)
    # nor across worlds: one world's bags against the model (a machine's bags, with no world, are one)
    mixed = [dataclasses.replace(m, world_mode="default" if i == 0 else m.world_mode) for i, m in enumerate(ds.metas)]
    with pytest.raises(ValueError, match=r"mixes worlds \['default', 'fee'\]"):
        build_frame(dataclasses.replace(ds, metas=mixed), stride=4)
    unknown = [dataclasses.replace(m, world_mode="" if i == 0 else m.world_mode) for i, m in enumerate(ds.metas)]
    assert len(build_frame(dataclasses.replace(ds, metas=unknown), stride=4).episodes) == len(full.episodes)
    # bags without a soil label are grouped by γ; a left-out labelled episode does not change that
    blind_metas = [dataclasses.replace(m, soil="unknown", relative_density_pct=float("nan")) for m in ds.metas]
    by_gamma = build_frame(dataclasses.replace(ds, metas=blind_metas), stride=4)
    blind_metas[0] = patched(ds.metas[0], two)  # labelled, but its soil changes: left out
    with_one = build_frame(dataclasses.replace(ds, metas=blind_metas), stride=4)
    assert by_gamma.group_by == with_one.group_by == "gamma" and not with_one.has_metadata()
    assert with_one.changing_soil == (ds.names[0],) and len(with_one.groups) == len(by_gamma.groups)


def test_an_episode_with_too_little_cutting_is_left_out_not_fitted(bag_dirs):
    """A blade that barely entered (a few ticks in the soil) gives nothing to fit a soil to: an
    episode with less than MIN_CUT_S of analysed cutting is left out and named; one with more is
    analysed; none left is refused with the reason."""
    from soil_discrepancy.frame import MIN_CUT_S

    ds = load_dataset(bag_dirs["control"])
    known = ds.known.copy()
    d = KNOWN_PARAMS.index("d")
    for e, keep_s in ((0, 0.5 * MIN_CUT_S), (1, 1.5 * MIN_CUT_S)):
        r = ds.episode_rows(e)
        rows = np.arange(r.start, r.stop)
        cut = rows[(rows >= r.start + 120) & (rows < r.start + 120 + int(keep_s * 60))]
        known[np.setdiff1d(rows, cut), d] = 0.0  # the blade above the soil but for keep_s
    frame = build_frame(dataclasses.replace(ds, known=known), stride=4)
    assert frame.too_short == (ds.names[0],) and 1 in set(frame.episodes) and 0 not in set(frame.episodes)
    known[:, d] = np.where(np.arange(len(known)) % 600 < 30, known[:, d], 0.0)  # every episode: 0.5 s at most
    with pytest.raises(ValueError, match=f"no episode of the {len(ds)} has {MIN_CUT_S:g} s of the blade in the soil"):
        build_frame(dataclasses.replace(ds, known=known), stride=4)


def test_without_a_soil_label_the_test_part_spans_the_unit_weights(bag_dirs):
    """No soil to stratify by: the held-out groups come one from each band of measured γ, so the
    test part covers the soils' range for every seed (a plain shuffle puts both test groups in
    one half of the 8 in 43 % of seeds)."""
    ds = load_dataset(bag_dirs["control"])
    metas = [dataclasses.replace(m, soil="unknown", relative_density_pct=float("nan")) for m in ds.metas]
    frame = build_frame(dataclasses.replace(ds, metas=metas), stride=4, group_by="gamma")
    assert not frame.has_metadata() and len(frame.groups) == 8
    gamma = frame.column("gamma")
    rank = {g: r for r, g in enumerate(sorted(frame.groups, key=lambda g: np.median(gamma[frame.group == g])))}
    tests = set()
    for seed in range(8):
        sel, test = split_holdout(frame, 0.3, seed=seed)
        assert len(test) == 2 and sorted(sel + test) == sorted(int(g) for g in frame.groups)
        assert sorted(rank[g] // 4 for g in test) == [0, 1], f"seed {seed}: test groups {test} in one half of γ"
        tests.add(tuple(test))
    assert len(tests) > 2, "the split is still seeded, not fixed"


def test_bags_without_a_soil_label_are_grouped_by_their_measured_unit_weight(bag_dirs):
    """group_by='gamma': the soil label is never read; episodes of one γ (a known parameter) share
    θ. On the fixture's 4 soils x 2 densities that is the labelled grouping, up to the names."""
    ds = load_dataset(bag_dirs["control"])
    labelled = build_frame(ds, stride=4)
    metas = [dataclasses.replace(m, soil="unknown", relative_density_pct=float("nan")) for m in ds.metas]
    by_gamma = build_frame(dataclasses.replace(ds, metas=metas), stride=4, group_by="gamma")
    assert set(by_gamma.soils) == {"unknown"} and all(n.startswith("γ≈") for n in by_gamma.group_names)
    same = {}
    for e in labelled.episodes:
        same.setdefault(int(labelled.group_of[e]), set()).add(int(by_gamma.group_of[e]))
    assert all(len(v) == 1 for v in same.values()) and len(set().union(*same.values())) == len(labelled.groups) == 8
    assert build_frame(ds, stride=4, group_by="gamma").group_names == by_gamma.group_names  # labels ignored
    # a soil test matches a soil label: γ groups have none, and the verdict's words do not ask for
    # --soil-tests there (the unlabelled run was told "a soil test tells (--soil-tests)", which it refuses)
    from soil_discrepancy.regimes import group_misfit
    from soil_discrepancy.verdict import _soil_test_hint
    for frame, testable in ((by_gamma, False), (labelled, True)):
        rows = [r for r in group_misfit(frame, 0.1 * frame.forces)["rows"] if r["kind"] == "group"]
        assert rows and all(r["testable"] is testable and r["range_checked"] is testable for r in rows), rows
        assert ("--soil-tests holds a group by its one soil label, which these groups lack" in _soil_test_hint(rows)) is not testable
    unlabelled = dataclasses.replace(ds, metas=metas)
    auto = build_frame(unlabelled, stride=4)  # the default on bags without any label: γ groups
    assert auto.group_by == "gamma" and auto.group_names == by_gamma.group_names
    known = np.array(ds.known, float, copy=True)
    known[:, KNOWN_PARAMS.index("gamma")] = 18e3  # a machine that records one configured γ for every soil
    one_gamma = build_frame(dataclasses.replace(unlabelled, known=known), stride=4)
    assert one_gamma.group_by == "episode" and len(one_gamma.groups) == len(ds.names)
    known[: ds.episode_rows(len(ds.names) // 2).start, KNOWN_PARAMS.index("gamma")] = 17e3
    two_gammas = build_frame(dataclasses.replace(unlabelled, known=known), stride=4)
    assert two_gammas.group_by == "episode", "two γ groups cannot be held out and cross-validated"
    known[: ds.episode_rows(len(ds.names) // 4).start, KNOWN_PARAMS.index("gamma")] = 16e3
    three_gammas = build_frame(dataclasses.replace(unlabelled, known=known), stride=4)
    assert three_gammas.group_by == "gamma" and len(three_gammas.groups) == 3
    with pytest.raises(ValueError, match="group_by='soil' must be one of"):
        build_frame(ds, stride=4, group_by="soil")


def test_unlabelled_bags_beside_labelled_ones_share_theta_by_their_unit_weight(bag_dirs):
    """A folder mixing a simulator's labelled bags with a machine's unlabelled ones: the unlabelled
    episodes share θ by measured γ, as they would alone (one θ per episode had taken in a hidden soil
    inertia, constant within an episode, and nothing was named), and the report's grouping says so."""
    ds = load_dataset(bag_dirs["control"])
    labelled = build_frame(ds, stride=4)
    half = [m.soil in ("Sand", "Gravel") for m in ds.metas]
    metas = [dataclasses.replace(m, soil="unknown", relative_density_pct=float("nan")) if h else m
             for m, h in zip(ds.metas, half)]
    mixed = build_frame(dataclasses.replace(ds, metas=metas), stride=4)
    assert mixed.group_by == "auto" and len(mixed.groups) == len(labelled.groups) == 8
    assert sorted(mixed.unlabelled_by_gamma) == sorted(n for n, h in zip(ds.names, half) if h)
    for e in mixed.episodes:  # the same episodes share θ as with every label read
        same = mixed.episodes[labelled.group_of[mixed.episodes] == labelled.group_of[e]]
        assert set(mixed.group_of[same]) == {mixed.group_of[e]}
        assert mixed.group_names[mixed.group_of[e]].startswith("unknown γ≈") == half[e]
    assert "measured γ for the episodes without a soil label" in _grouping(mixed)
    assert build_frame(ds, stride=4).unlabelled_by_gamma == ()


def test_prediction_hook_compares_any_models_predictions(bag_dirs):
    frame = build_frame(load_dataset(bag_dirs["control"]), stride=6)
    test = frame.select(groups=[0, 1])
    before = test.forces + 1000.0
    after = test.forces + 100.0
    comp = compare_predictions(test, before, after, label="PINN")
    assert comp["before"]["rmse"] == pytest.approx(math.sqrt(2) * 1000.0)
    assert comp["after"]["mae_x"] == pytest.approx(100.0) and comp["rmse_ratio"] == pytest.approx(0.1)
    assert comp["improved_episodes"] == comp["n_episodes"] == 8 and comp["by_regime"]
    with pytest.raises(ValueError, match="shape"):
        compare_predictions(test, before[:-1], after)


def test_the_force_at_another_depth_from_one_depth_shows_a_missing_term_and_not_a_wrong_one(bag_dirs):
    """depth_forecast_gap: θ fitted on one episode, the force of another episode of the group at
    another depth. With soil inertia hidden, adding it shrinks that error; on the control, adding
    it makes the error grow (the confirmation then fails)."""
    for name, better in (("soil_inertia", True), ("control", False)):
        frame = build_frame(load_dataset(bag_dirs[name]), stride=4)
        test = frame.select(groups=frame.groups[:4])
        fc = depth_forecast_gap(test, AugmentedFEE(()), AugmentedFEE((("soil_inertia", 4.0),)))
        assert fc["pairs"] == 4 * 2 * 2 * 2, "per group: 2 speeds x 2 depths, each episode to the two at the other depth"
        if better:
            assert fc["reduction"] > 0.2 and fc["p_paired"] < 0.05, fc
        else:
            assert fc["reduction"] < 0.0 and fc["p_paired"] > 0.5, fc
        assert fc["before"]["x_bias_deeper_pct"] is not None and fc["after"]["vector_pct"] >= 0.0


def test_a_form_is_confirmed_by_the_force_error_or_without_worsening_it_by_the_forecast():
    from soil_discrepancy.workflow import _confirmed

    def held_out(sse, red, p):
        return {"sse_reduction": sse, "depth_forecast": {"reduction": red, "p_paired": p}}
    assert _confirmed(held_out(0.06, None, 1.0), 0.05, 0.01)
    assert _confirmed(held_out(0.02, 0.17, 1e-6), 0.05, 0.01)  # the default world's surcharge relief
    assert not _confirmed(held_out(-0.03, 0.18, 1e-7), 0.05, 0.01)  # a better forecast bought with a worse force
    assert not _confirmed(held_out(0.02, 0.17, 0.2), 0.05, 0.01)
    assert not _confirmed(held_out(0.02, 0.03, 1e-6), 0.05, 0.01)
    assert not _confirmed(held_out(None, None, 1.0), 0.05, 0.01)


def test_prediction_hook_is_called_on_the_heldout_episodes(reports):
    rep = reports["soil_inertia"]
    (test_frame, before, after, context), = HOOK_CALLS
    assert before.terms == () and after.names == ("soil_inertia",)
    assert context["test_episodes"] == rep["data"]["test_episodes"] == sorted({test_frame.names[e] for e in test_frame.episodes})
    assert context["selection_episodes"] == rep["data"]["selection_episodes"] and context["dataset"] is not None
    comp = rep["test"]["predictors"]["fake PINN"]
    assert comp["rmse_ratio"] == pytest.approx(0.1) and comp["episodes"] == rep["test"]["episodes"]


def test_cli_retrains_the_pinn_with_the_named_effect_and_checks_the_hidden_one(bag_dirs, tmp_path, capsys):
    """Step 5 for the PINN (real training, a few epochs): the PINN retrained with the named effect
    has a better physics part (F̂ − F_r) on the held-out episodes; --hidden only checks the answer."""
    out = tmp_path / "inertia"
    assert cli_main([str(bag_dirs["soil_inertia"]), "--out", str(out), "--stride", "6", "--workers", "2", "--quiet",
                     "--no-plots", "--pinn-epochs", "4", "--hidden", "soil_inertia=4"]) == 0
    rep = json.loads((out / "discrepancy.json").read_text())
    pinn = rep["test"]["predictors"]["PINN"]
    split, held = pinn["split"], set(rep["data"]["test_episodes"])
    assert pinn["terms"][0][0] == "soil_inertia" and pinn["terms_before"] == []
    # scored episodes: held-out ones that neither PINN nor the fit of k has seen
    assert set(split["test"]) | set(split["calibration"]) == held and not set(split["test"]) & set(split["train"])
    assert set(split["calibration"]) <= set(split["train"]) and not set(split["val"]) & held
    rows = pinn["comparisons"]
    assert rows["FEE"]["episodes"] == rows["soil"]["episodes"] == sorted(split["test"])
    assert rows["FEE"]["after"]["rmse"] < rows["FEE"]["before"]["rmse"]
    groups = {g for g in rep["data"]["test_groups"]}
    for label in ("before", "after"):
        assert {r["group"] for r in pinn["theta"][label]} == groups
        assert all(r["success"] and math.isfinite(r["phi_deg"] + r["c_pa"] + r["delta_deg"]) for r in pinn["theta"][label])
    # 4 epochs on 20-odd episodes teach the PINN little: that it helps is test_pinn_with_the_named_effect_...
    assert rep["hidden_check"]["correct"] and rep["hidden_check"]["heldout_error_ratio"] <= 0.5
    md = (out / "discrepancy.md").read_text()
    assert "PINN retrained with the named effect" in md and "Check against the hidden effect" in md
    assert "named ['soil_inertia']" in capsys.readouterr().out
    # the control with the same options: test_control_gives_no_effect_through_the_cli_...


def test_pinns_trained_in_parallel_processes_give_what_they_give_one_after_another(bag_dirs):
    """pinn_gap's workers: the same PINNs (seeds, split, one torch thread each) trained two at a
    time in spawned processes give the same comparison to the last digit; a bad count is named."""
    from soil_discrepancy.pinn_check import pinn_gap

    ds = blind(bag_dirs["soil_inertia"])
    frame = build_frame(ds, stride=6)
    sel, held = split_holdout(frame, 0.3, 0)
    args = (ds, frame.select(groups=held), frame.episode_names(sel), AugmentedFEE(), AugmentedFEE([("soil_inertia", 4.0)]))
    kw = dict(epochs=1, seed=0, seeds=2, stride=8, eval_stride=20, log=None)
    one = pinn_gap(*args, threads=1, workers=1, **kw)
    two = pinn_gap(*args, threads=1, workers=2, **kw)
    assert one["per_seed"] == two["per_seed"] and len(two["per_seed"]["soil_rmse_after"]) == 2
    assert one["comparisons"] == two["comparisons"] and one["theta"] == two["theta"]
    assert [t["epochs_run"] for t in two["train"]["before"] + two["train"]["after"]] == [1] * 4
    assert two["threads_per_pinn"] == 1
    for bad in ({"workers": 0}, {"threads": 0}, {"workers": True}):
        with pytest.raises(ValueError, match=f"{next(iter(bad))}="):
            pinn_gap(*args, **bad, **kw)


def test_pinn_with_the_named_effect_has_better_soil_estimates_at_full_size():
    """Step 5 for the PINN, at the data size of the committed report (``make discrepancy``'s
    soil-inertia case: 108 episodes; 20 epochs where the report trains 30, and one PINN per physics
    where it trains an ensemble of 3, whose members alone give 0.68, 0.65 and 0.83 of the error): retrained with
    the named effect, the PINN's soil estimates,
    pooled per soil group, explain the held-out force at every depth and speed better than the
    paper's PINN, whose estimates absorb the missing effect (pinn_check docstring)."""
    from soil_discrepancy.pinn_check import pinn_gap

    specs = grid_specs(list(SOILS), [0.0, 40.0, 80.0], [0.3, 0.65, 1.0], [0.1, 0.175, 0.25], 1, seed_base=100,
                       duration_s=10.0)
    ds = simulated(specs, HIDDEN["soil_inertia"])
    frame = build_frame(ds, stride=2)
    sel, held = split_holdout(frame, 0.3, 0)
    selection = frame.episode_names(sel)
    got = pinn_gap(ds, frame.select(groups=held), selection, AugmentedFEE(), AugmentedFEE([("soil_inertia", 4.0)]),
                   epochs=20, seed=0, seeds=1, max_minutes=12.0, log=None,
                   threads=1, workers=2)  # one process and torch thread per PINN: two threads of one wait on each other beside a busy core
    rows = got["comparisons"]
    soil, fee_rows = rows["soil"], rows["FEE"]
    print(f"\nsoil-estimate RMSE {soil['before']['rmse']:.0f} -> {soil['after']['rmse']:.0f} N, "
          f"improved {soil['improved_episodes']}/{soil['n_episodes']}")
    # seed 0 here: 0.51 (17/20 episodes better; 0.61 after 30 epochs); the report's ensemble 0.63,
    # other splits 0.82, 0.94
    assert soil["after"]["rmse"] <= 0.9 * soil["before"]["rmse"], (soil["before"], soil["after"], got["per_seed"])
    assert soil["improved_episodes"] > soil["n_episodes"] / 2
    assert fee_rows["after"]["rmse"] <= 0.6 * fee_rows["before"]["rmse"]
    assert [t["epochs_run"] for t in got["train"]["before"] + got["train"]["after"]] == [20] * 2
    assert len(got["per_seed"]["soil_rmse_after"]) == 1


def test_a_soil_the_model_cannot_follow_is_located_by_its_misfit(bag_dirs):
    """θ per group absorbs a group's bias, not a form it cannot follow: the residual's spread locates
    an effect that acts in one soil. Real frame, residuals made up: every episode's residual is
    noise of 3 % of its |F|, the clay episodes' 9 %; a second frame with no such soil flags none."""
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.regimes import group_misfit
    from soil_discrepancy.verdict import misfit_text

    frame = build_frame(blind(bag_dirs["control"]), stride=4)
    rng = np.random.default_rng(0)
    fmag = np.hypot(frame.forces[:, 0], frame.forces[:, 1])[:, None]
    clay = (np.array(frame.soils)[frame.episode] == "Clay")[:, None]
    resid = rng.normal(size=frame.forces.shape) * fmag * np.where(clay, 0.09, 0.03)
    table = [{"group": n, "phi_deg": 5.0 if n.startswith("Clay") else 30.0, "c_pa": 0.0, "delta_deg": 15.0}
             for n in frame.group_names]
    mis = group_misfit(frame, resid, theta_table=table)
    assert mis["soils"] == ["Clay"], mis["rows"]
    row = next(r for r in mis["rows"] if r["kind"] == "soil" and r["name"] == "Clay")
    assert 2.5 < row["ratio"] < 3.5 and row["p_holm"] < 0.01
    clay_groups = [r for r in mis["rows"] if r["kind"] == "group" and r["name"].startswith("Clay")]
    assert clay_groups and all(r["theta_at_bound"] == ["φ at its lower bound"] for r in clay_groups)
    assert not [r for r in mis["rows"] if r["kind"] == "group" and not r["name"].startswith("Clay") and r["theta_at_bound"]]
    text = misfit_text({"misfit": mis})
    assert "soil Clay" in text and "φ at its lower bound" in text and "the model needs a soil outside" in text
    # three target depths per group: not one depth; cut at one depth, φ and c trade off and a θ on its
    # box says nothing about the physics (an outside reader's pure-FEE control said it did)
    assert all(r["depth_span_m"] > 0.05 for r in mis["rows"] if r["kind"] == "group")
    assert not any(r["one_depth"] for r in mis["rows"])
    one = {"misfit": {**mis, "rows": [{**r, "depth_span_m": 0.004, "one_depth": True} if r["kind"] == "group" else r
                                      for r in mis["rows"]]}}
    text = misfit_text(one)
    assert "cut at one depth" in text and "says nothing about the physics" in text and "needs a soil outside" not in text
    # with no regime flagged and no soil fitting worse, θ on the physical box where cuts of several depths pin
    # it is a discrepancy by itself (an outside reader's φ falling with depth had been "no significant
    # discrepancy"); cut at one depth it is not
    from soil_discrepancy.verdict import verdict_of

    quiet_bound = {"misfit": {**mis, "rows": [{**r, "flagged": False} for r in mis["rows"]], "soils": [], "groups": []},
                   "significant": False, "flagged_variables": [], "min_effect": 0.02, "alpha": 0.01}
    verdict, text = verdict_of([], quiet_bound, None)
    assert verdict == "unexplained" and "only with a soil outside the physical range in 2 group(s)" in text, text
    verdict, text = verdict_of([], {**quiet_bound, "misfit": {**quiet_bound["misfit"], "rows": [
        {**r, "one_depth": True} for r in quiet_bound["misfit"]["rows"]]}}, None)
    assert verdict == "no significant discrepancy", text
    even = group_misfit(frame, rng.normal(size=frame.forces.shape) * fmag * 0.03)
    assert even["soils"] == [] and even["groups"] == [] and misfit_text({"misfit": even}) == ""


def test_a_soil_that_fits_worse_by_more_than_the_least_effect_is_a_discrepancy_not_a_caution(bag_dirs):
    """An outside reader's drag while the blade speeds up: θ took it in as the dense clay's and loam's
    bias, no regime bin was biased, and the report said "no significant discrepancy" beside a misfit
    table naming the two soils at 5× the others'. A labelled soil that fits worse by at least the
    regime tests' least effect (2 % of |F|, in quadrature beyond the others') is now itself a
    discrepancy, "unexplained" where nothing named explains it, and "partly explained" beside named
    terms it does not leave; one worse only by tenths of a percent, or a γ-group (two soils of one γ
    share a θ), stays a caution. Real frame, residuals made up."""
    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.regimes import group_misfit, misfit_discrepancy, unit_episodes
    from soil_discrepancy.verdict import verdict_of
    from soil_msgs_py.soil_labels import gamma_group_names

    frame = build_frame(blind(bag_dirs["control"]), stride=4)
    rng = np.random.default_rng(0)
    fmag = np.hypot(frame.forces[:, 0], frame.forces[:, 1])[:, None]
    clay = (np.array(frame.soils)[frame.episode] == "Clay")[:, None]
    noise = rng.normal(size=frame.forces.shape) * fmag

    def reg(clay_share, others_share):
        mis = group_misfit(frame, noise * np.where(clay, clay_share, others_share))
        return {"significant": False, "flagged_variables": [], "min_effect": 0.02, "alpha": 0.01, "misfit": mis}

    worse = reg(0.09, 0.03)  # the clay's misfit 9 % against 3 %: 8.5 % beyond it
    found = [r["name"] for r in misfit_discrepancy(worse)]
    assert "Clay" in found and all(n.startswith("Clay") for n in found), worse["misfit"]["rows"]
    verdict, text = verdict_of([], worse, None)
    assert verdict == "unexplained" and "some soils fit worse than the others, by at least 2 % of |F|" in text, text
    assert "the model fits worse in soil Clay" in text and "an effect that acts there" in text, text
    # as flagged (3×, Holm p < 0.01), but 0.9 % against 0.3 % is no effect a model of the soil misses
    slight = reg(0.009, 0.003)
    assert slight["misfit"]["soils"] == ["Clay"] and misfit_discrepancy(slight) == [], slight["misfit"]["rows"]
    verdict, text = verdict_of([], slight, None)
    assert verdict == "no significant discrepancy" and "; but the model fits worse in soil Clay" in text, text
    # a γ-group of unlabelled bags: a caution only, however worse
    name = gamma_group_names([18e3])[0]
    gamma = {**worse, "misfit": {**worse["misfit"], "groups": [name], "soils": [],
                                 "rows": [{"kind": "group", "name": name, "ratio": 5.0, "flagged": True, "misfit": 0.1,
                                           "misfit_others": 0.02, "theta_at_bound": []}]}}
    assert misfit_discrepancy(gamma) == [] and verdict_of([], gamma, None)[0] == "no significant discrepancy"
    # an effect of the loose soils, in a group of every soil: each group against all the others, the
    # other loose groups among them, was flagged in none (an outside reader's drag at I_d 0 %: 17-22×);
    # the rows per density compare every soil at one density with the rest
    loose = (np.array(frame.densities)[frame.episode] == 20.0)[:, None]
    mis = group_misfit(frame, noise * np.where(loose, 0.09, 0.03))
    assert mis["densities"] == ["I_d=20%"] and mis["soils"] == [], mis["rows"]
    row = next(r for r in mis["rows"] if r["kind"] == "density" and r["name"] == "I_d=20%")
    assert row["n_episodes"] == int(np.sum(np.array(frame.densities)[frame.episodes] == 20.0)) and row["ratio"] > 2.5
    verdict, text = verdict_of([], {**worse, "misfit": mis}, None)
    assert verdict == "unexplained" and "the model fits worse in the soils at I_d=20% (" in text, text
    # each row's episodes, as the held-out part's blind spots are found by
    assert unit_episodes(frame, row) == {int(e) for e in frame.episodes if frame.densities[e] == 20.0}
    clay_row = next(r for r in worse["misfit"]["rows"] if r["kind"] == "soil" and r["name"] == "Clay")
    assert unit_episodes(frame, clay_row) == {int(e) for e in frame.episodes if frame.soils[e] == "Clay"}
    group_row = next(r for r in mis["rows"] if r["kind"] == "group")
    assert unit_episodes(frame, group_row) == {int(e) for e in frame.episodes
                                               if frame.group_names[frame.group_of[e]] == group_row["name"]}
    # the unlabelled episodes' soil row beside labelled bags ("unknown": γ-groups inside) stays a caution
    unknown = {**worse, "misfit": {**worse["misfit"], "soils": ["unknown"], "groups": [], "densities": [],
                                   "rows": [{"kind": "soil", "name": "unknown", "ratio": 5.0, "flagged": True,
                                             "misfit": 0.1, "misfit_others": 0.02, "theta_at_bound": []}]}}
    assert misfit_discrepancy(unknown) == []
    # the held-out part holds none of the loose soils (split by soil, not density): the verdict says its
    # figures cannot judge an effect there, and why a tentative form failed it (a force error that fell
    # by half beside "not the held-out test" read as a contradiction: the forecast had failed it)
    forms = {"not_confirmed": {"forms": ["form:-wd_x*enter2"], "test_rmse_before": 2330.0, "test_rmse_after": 1027.0,
                               "sse_reduction": 0.81, "forecast_reduction": -0.118, "forecast_pct_before": 21.5,
                               "forecast_pct_after": 24.0, "forecast_p": 0.6, "min_gain": 0.05, "alpha": 0.01}}
    test = {"before": {"rmse": 489.0}, "after": {"rmse": 489.0}, "fits_worse_untested": ["the soils at I_d=20%"],
            "fits_worse_unselected": ["soil Clay"]}
    text = verdict_of([], {**worse, "misfit": mis}, test, None, forms)[1]
    assert ("but the held-out test part holds no episode of the soils at I_d=20%, where the baseline fits worse: its "
            "figures cannot judge an effect there; and the selection part holds no episode of soil Clay") in text, text
    assert ("2330 -> 1027 N, force at another depth 21.5 -> 24.0 % of |F|: the force at another depth gets worse, its "
            "error up 12 %, more than the least gain (5 %)") in text, text
    short = {**forms["not_confirmed"], "sse_reduction": 0.03, "forecast_reduction": 0.01}
    assert "the force error's squares fall by 3 %, less than the least gain (5 %)" in verdict_of(
        [], {**worse, "misfit": mis}, None, None, {"not_confirmed": short})[1]
    # beside named terms that leave the clay's misfit: "partly explained", the structure in the soils' fit said
    named = [TermScore(name="soil_inertia", k=4.0, k_se=0.1, k_folds=[4.0] * 5, gain=0.4, p=1e-9)]
    test = {"before": {"rmse": 712.0}, "after": {"rmse": 443.0}}
    pins = {"soil_inertia": {"pinned": True}}
    verdict, text = verdict_of(named, {"significant": True, "flagged_variables": ["d"]}, test, worse, pins=pins)
    assert verdict == "partly explained" and "structure remains in some soils' fit, in no regime" in text, text
    assert verdict_of(named, {"significant": True, "flagged_variables": ["d"]}, test, reg(0.03, 0.03),
                      pins=pins)[0] == "explained"


def test_the_workflow_searches_forms_for_soils_that_fit_worse_and_says_the_held_out_parts_blind_spots(bag_dirs, tmp_path):
    """The whole workflow on the control's real frame with a drag made up in the loose soils only
    (3 γ w d² v_x at I_d 20 %, every soil): with the row per density the baseline "fits worse in the
    soils at I_d=20%", the library's forms are searched for it (no regime need be flagged), and where
    the soil-stratified held-out (or selection) part holds no loose group the verdict says its figures
    cannot judge an effect there, on the final held-out figures."""
    from dataclasses import replace

    from soil_discrepancy.candidates import split_holdout
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.workflow import run_discrepancy
    from soil_msgs_py.params import KNOWN_PARAMS

    frame = build_frame(blind(bag_dirs["control"]), stride=6)
    k = {n: frame.known[:, KNOWN_PARAMS.index(n)] for n in ("gamma", "d", "w", "v_x")}
    loose = np.array(frame.densities)[frame.episode] == 20.0
    drag = np.where(loose, 3.0 * k["gamma"] * k["w"] * k["d"] ** 2 * k["v_x"], 0.0)  # [N], v_x per 1 m/s
    made = replace(frame, forces=frame.forces + np.stack([drag, np.zeros_like(drag)], axis=1))
    # a seed whose held-out part holds a loose group, and one whose does not (the split is by soil)
    loose_held = {seed: any(made.group_names[g].endswith("I_d=20%") for g in split_holdout(made, RUN["holdout"], seed)[1])
                  for seed in range(12)}
    for seed in (min(s for s, v in loose_held.items() if v), min(s for s, v in loose_held.items() if not v)):
        rep = run_discrepancy(frame=made, out_dir=tmp_path / str(seed), **{**RUN, "seed": seed}, plots=False)
        assert rep["regimes"]["misfit"]["densities"] == ["I_d=20%"], rep["regimes"]["misfit"]["rows"]
        assert rep["forms"]["searched"] and "the soils at I_d=20%" in rep["forms"]["fits_worse_in"], rep["forms"]
        assert (rep["test"]["fits_worse_untested"] == []) == loose_held[seed], (seed, rep["test"]["fits_worse_untested"])
        said = "the held-out test part holds no episode of the soils at I_d=20%, where the baseline fits worse"
        assert (said in rep["summary"]) != loose_held[seed], rep["summary"]
        assert rep["verdict"] != "no significant discrepancy", rep["summary"]


def test_a_form_of_travel_says_that_at_one_speed_per_episode_travel_is_speed_times_time(bag_dirs):
    """An outside reader's drag ∝ v_x τ (speed times time in soil) was named w d · s (travel),
    "pinned down", beside compaction's travel as "the same mechanism": with one speed per episode the
    two columns are one (s ≈ v_x τ within 3 % on the grids), which the verdict now says of a form of
    travel or of time. Real frame: its cuts at one speed each; the same frame with travel doubled in
    half its episodes (no longer speed × time) is not; a form of depth says nothing of it."""
    from dataclasses import replace

    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.regimes import travel_is_speed_times_time
    from soil_discrepancy.verdict import verdict_of

    frame = build_frame(blind(bag_dirs["control"]), stride=4)
    assert travel_is_speed_times_time(frame)
    odd = np.isin(frame.episode, frame.episodes[::2])
    assert not travel_is_speed_times_time(replace(frame, distance=np.where(odd, 2.0 * frame.distance, frame.distance)))
    reg = {"significant": True, "flagged_variables": ["distance"], "travel_is_speed_times_time": True}
    test = {"before": {"rmse": 1758.0}, "after": {"rmse": 505.0}}
    said = "each episode was cut at one speed, so travel is speed × time in soil here (s = v_x τ): a law of time"
    for name, caveat in (("form:wd_x*s", said), ("form:wd_x*tenter3", "a law of travel fits as well"),
                         ("form:gd2w_x*vx", None)):
        named = [TermScore(name=name, k=0.15, k_se=0.001, k_folds=[0.15] * 5, gain=0.97, p=1e-9)]
        text = verdict_of(named, reg, test, None, pins={name: {"pinned": True}})[1]
        assert (caveat in text) if caveat else "speed × time" not in text, text
        assert "speed × time" not in verdict_of(named, {**reg, "travel_is_speed_times_time": False}, test, None,
                                                 pins={name: {"pinned": True}})[1]


def test_a_term_of_travel_says_that_where_every_cut_entered_the_soil_at_one_place_travel_is_position(bag_dirs):
    """An outside tester's soil strengthening along the path from x = 3 m on (0.08 (x_b − 3 m)+ F_FEE)
    was named compaction by travel, "explained", "pinned down: yes": every episode of a batch grid
    enters the soil at x = 2 m, so travel in soil is position along the path, and a law of one fits as
    a law of the other. Real frame: its entries at one place; the same frame with half its episodes
    entering 3 m farther on is not; the verdict says it of a catalogue term and a form of travel, not of
    one of depth."""
    from dataclasses import replace

    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.regimes import travel_is_position
    from soil_discrepancy.verdict import verdict_of

    frame = build_frame(blind(bag_dirs["control"]), stride=4)
    x = travel_is_position(frame)
    assert x is not None and 1.9 < x < 2.3, x
    moved = frame.entry_x_m.copy()
    moved[frame.episodes[::2]] += 3.0
    assert travel_is_position(replace(frame, entry_x_m=moved)) is None
    test = {"before": {"rmse": 1832.0}, "after": {"rmse": 565.0}}
    said = "every episode entered the soil at one place along the path (x ≈ 2.0 m), so travel in soil is position"
    for name, says in (("compaction_hardening", True), ("form:wd_x*s", True), ("form:gd2w_x*vx", False)):
        named = [TermScore(name=name, k=0.08, k_se=0.001, k_folds=[0.08] * 5, gain=0.93, p=1e-9)]
        for where, expect in ((2.0, says), (None, False)):
            reg = {"significant": False, "flagged_variables": [], "travel_is_position_m": where}
            text = verdict_of(named, reg, test, None, pins={name: {"pinned": True}})[1]
            assert (said in text) == expect, text


def test_a_term_of_time_in_soil_says_that_where_every_cut_began_at_one_moment_time_in_soil_is_the_clock(bag_dirs):
    """An outside reader's load cell whose gain drifts with the recording's clock (0.2 F_FEE t / 10 s)
    was named "time in soil × the FEE force" and nothing said that every episode of a batch grid cuts
    from its first tick, so τ is the clock. Real frame: its cuts begin at one moment; the same frame
    with half its recordings started 4 s earlier is not; the verdict says it of a form of τ only."""
    from dataclasses import replace

    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.regimes import time_in_soil_is_clock
    from soil_discrepancy.verdict import verdict_of

    frame = build_frame(blind(bag_dirs["control"]), stride=4)
    t0 = time_in_soil_is_clock(frame)
    assert t0 is not None and 0.0 <= t0 < 1.0, t0
    later = frame.t + np.where(np.isin(frame.episode, frame.episodes[::2]), 4.0, 0.0)
    assert time_in_soil_is_clock(replace(frame, t=later)) is None
    test = {"before": {"rmse": 832.0}, "after": {"rmse": 512.0}}
    said = "every recording's cut began at one moment of it (t ≈ 0.0 s), so time in soil is the recording's clock"
    for name, says in (("form:fee*tau", True), ("form:wd_x*s", False), ("soil_inertia", False)):
        named = [TermScore(name=name, k=0.2, k_se=0.003, k_folds=[0.2] * 5, gain=0.6, p=1e-9)]
        for when, expect in ((0.0, says), (None, False)):
            reg = {"significant": False, "flagged_variables": [], "time_in_soil_is_clock_s": when}
            text = verdict_of(named, reg, test, None, pins={name: {"pinned": True}})[1]
            assert (said in text) == expect, text


@pytest.mark.parametrize("sse, red, p, ok, said", [
    (0.30, 0.00, 0.5, True, ""),  # the force error falls by more than the least gain
    (0.81, -0.118, 0.6, False, "the force at another depth gets worse, its error up 12 %"),
    (0.81, float("nan"), None, False, "the force at another depth is undefined with them"),
    (0.02, 0.20, 0.001, True, ""),  # the forecast confirms what the force error does not
    (0.02, 0.20, 0.30, False, "by 20 %, not significantly (paired p 0.3)"),
    (0.02, 0.03, 0.001, False, "the force error's squares fall by 2 %, less than the least gain (5 %), and the force at "
                               "another depth's error by 3 %, less than it too"),
    (0.02, None, None, False, "the force at another depth is not measured"),
    (-0.30, 0.20, 0.001, False, "the force error rises, its squares up 30 %"),
    (None, 0.20, 0.001, False, "the force error is undefined"),
])
def test_the_held_out_confirmation_says_why_it_fails(sse, red, p, ok, said):
    """One rule (``gap.confirmation``) confirms named terms on the held-out episodes and says why it
    does not: a tentative form whose force error fell 2330 -> 1027 N "but not the held-out test" read
    as a contradiction (its forecast at another depth was 12 % worse). The workflow's ``_confirmed``
    and the verdict's reason are the same call; a set the rule confirms gets no reason."""
    from soil_discrepancy.gap import confirmation
    from soil_discrepancy.verdict import unconfirmed_reason
    from soil_discrepancy.workflow import _confirmed

    got, why = confirmation(sse, red, p, 0.05, 0.01)
    assert got == ok and said in why and (why == "") == ok, why
    test = {"sse_reduction": sse, "depth_forecast": {"reduction": red, **({} if p is None else {"p_paired": p})}}
    assert _confirmed(test, 0.05, 0.01) == ok
    figures = {"sse_reduction": sse, "forecast_reduction": red, "forecast_p": p, "min_gain": 0.05, "alpha": 0.01}
    assert unconfirmed_reason(figures) == why and unconfirmed_reason({**figures, "alpha": None}) == ""


def test_fitted_soils_outside_their_labels_textbook_ranges_are_said_beside_no_discrepancy_or_named_terms(bag_dirs):
    """An outside tester's drag ∝ d^1.5 (47 % of the FEE force) read as "no significant discrepancy":
    θ had taken it in, clays fitted at φ 35° where the textbook has 17-27°. The verdict now says where
    the fitted soil lies outside its label's range (loose to dense, ``soils.CATALOGUE``, with a margin);
    a label of no catalogue soil, and bags without labels, are not judged."""
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.regimes import group_misfit
    from soil_discrepancy.verdict import verdict_of

    frame = build_frame(blind(bag_dirs["control"]), stride=4)
    fmag = np.hypot(frame.forces[:, 0], frame.forces[:, 1])[:, None]
    resid = np.random.default_rng(0).normal(size=frame.forces.shape) * fmag * 0.03
    table = [{"group": n, "phi_deg": 35.0 if n.startswith("Clay") else 30.0, "c_pa": 5e3 if n.startswith(("Clay", "Loam")) else 0.0,
              "delta_deg": 15.0} for n in frame.group_names]
    mis = group_misfit(frame, resid, theta_table=table)
    off = {r["name"]: r["theta_off_label"] for r in mis["rows"] if r["kind"] == "group" and r["theta_off_label"]}
    assert off and all(n.startswith("Clay") for n in off) and all(v == ["φ 35.0° (Clay: 17–27°)"] for v in off.values()), off
    quiet = {"significant": False, "flagged_variables": [], "min_effect": 0.02, "alpha": 0.01, "misfit": mis}
    verdict, text = verdict_of([], quiet, None)
    assert verdict == "no significant discrepancy" and f"outside its label's textbook range in {len(off)}/" in text, text
    assert "soil tests (--soil-tests) tell" in text
    inside = group_misfit(frame, resid, theta_table=[{**t, "phi_deg": 22.0 if t["group"].startswith("Clay") else 30.0}
                                                    for t in table])
    assert verdict_of([], {**quiet, "misfit": inside}, None)[1].endswith("reduces the held-out error"), "nothing said"
    # beside named terms too, pinned down or not: an outside reader's z force ∝ √d was named as a constant
    # force, "pinned down" among the library's forms, and "explained", with loose sand fitted at φ 21° for 28°
    from soil_discrepancy.candidates import TermScore

    named = [TermScore(name="form:one_z*1", k=1.39, k_se=0.04, k_folds=[1.39] * 5, gain=0.4, p=1e-9)]
    test = {"before": {"rmse": 712.0}, "after": {"rmse": 443.0}}
    pins = {"form:one_z*1": {"pinned": True}}
    verdict, text = verdict_of(named, {"significant": True, "flagged_variables": ["d"]}, test, quiet, pins=pins)
    assert verdict == "partly explained" and "the soil fitted beside them lies outside its label's textbook range" in text
    assert "stand-ins" in text and "soil tests (--soil-tests) tell" in text, text
    verdict, text = verdict_of(named, {"significant": True, "flagged_variables": ["d"]}, test, {**quiet, "misfit": inside},
                               pins=pins)
    assert verdict == "explained" and "textbook" not in text, text
    # a run that had soil tests is not told to give them
    tested = {**mis, "rows": [{**r, "tested_parameters": 2} for r in mis["rows"]]}
    text = verdict_of(named, {"significant": True, "flagged_variables": ["d"]}, test, {**quiet, "misfit": tested}, pins=pins)[1]
    assert "--soil-tests" not in text and "the soil tests given bound θ only where they test it" in text, text


def test_a_gamma_group_that_fits_worse_is_said_to_be_possibly_two_soils():
    """Bags without soil labels are grouped by γ; two soils of one γ share one θ and fit worse with
    no effect missing, which the caution says (a user read it as an effect acting in that soil)."""
    from soil_discrepancy.verdict import misfit_text
    from soil_msgs_py.soil_labels import gamma_group_names

    name = gamma_group_names([18e3])[0]
    mis = {"rows": [{"kind": "group", "name": name, "ratio": 96.6, "theta_at_bound": []}], "soils": [], "groups": [name]}
    text = misfit_text({"misfit": mis}, quiet=True)
    assert text.startswith(f"; but the model fits worse in {name} (96.6×") and "is a group by unit weight" in text
    # unlabelled bags beside labelled ones: their γ group is "unknown γ≈…" (the caution was left out there)
    mixed = {"rows": [{"kind": "group", "name": f"unknown {name}", "ratio": 13.6, "theta_at_bound": []}], "soils": [],
             "groups": [f"unknown {name}"]}
    assert "is a group by unit weight" in misfit_text({"misfit": mixed}, quiet=True)
    labelled = {"rows": [{"kind": "group", "name": "Clay 80 %", "ratio": 5.0, "theta_at_bound": []}], "soils": [],
                "groups": ["Clay 80 %"]}
    assert "unit weight" not in misfit_text({"misfit": labelled})


def test_the_fast_part_of_a_residual_is_its_noise_floor(bag_dirs):
    """White noise of 400 N (x) and 100 N (z) on a slow 3 kN swing: the fast part reads the noise, not the swing."""
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.regimes import fast_part

    frame = build_frame(blind(bag_dirs["control"]), stride=2)
    rng = np.random.default_rng(1)
    slow = np.repeat(3000.0 * np.sin(2 * np.pi * frame.t / 10.0)[:, None], 2, axis=1)
    fast = fast_part(frame, slow + rng.normal(size=frame.forces.shape) * [400.0, 100.0])
    assert fast["x"] == pytest.approx(400.0, rel=0.05) and fast["z"] == pytest.approx(100.0, rel=0.1)
    assert fast_part(frame, slow)["x"] < 30.0


def test_the_frame_analyses_the_soils_force_without_the_blades_inertia(bag_dirs):
    """The soil's force is the measured one less m_b·a (a model of the soil explains no inertia);
    across a gap of a repaired bag no acceleration is known, so nothing is taken off there."""
    from soil_discrepancy.frame import build_frame
    from soil_physics.blade_inertia import blade_velocity, inertia_force_rows

    ds = blind(bag_dirs["soil_inertia"])
    frame = build_frame(ds, stride=1)
    np.testing.assert_allclose(frame.forces + frame.inertia, ds.forces[frame.rows])
    e = int(frame.episodes[0])
    rows = ds.episode_rows(e)
    v = blade_velocity(ds.observations[rows])
    want = np.stack(inertia_force_rows(v[:, 0], v[:, 1]), 1)[frame.rows[frame.episode == e] - rows.start]
    np.testing.assert_allclose(frame.inertia[frame.episode == e], want)
    assert np.abs(frame.inertia[:, 1]).max() > 100.0  # the blade does accelerate vertically
    gap = ds.gap_before.copy()
    gap[frame.rows[10]] = True
    gapped = build_frame(dataclasses.replace(ds, gap_before=gap), stride=1)
    assert np.all(gapped.inertia[10] == 0.0) and gapped.forces[10] == pytest.approx(ds.forces[frame.rows[10]])
    np.testing.assert_array_equal(gapped.inertia[11:], frame.inertia[11:])


def test_a_term_that_makes_the_forecast_at_another_depth_worse_is_not_confirmed():
    """The force error alone is not enough: a term the held-out episodes find 7 % better in force but
    25 % worse at another depth (a constant drag named as a relief below 0.1 m did that) is not named;
    1.6 % worse is within the least gain; a forecast gain needs its paired test."""
    from soil_discrepancy.workflow import _confirmed

    def test(sse, reduction, p=1.0):
        return {"sse_reduction": sse, "depth_forecast": {"reduction": reduction, "p_paired": p}}

    assert not _confirmed(test(0.07, -0.25), 0.05, 0.01)
    assert _confirmed(test(0.07, -0.016), 0.05, 0.01) and _confirmed(test(0.07, None), 0.05, 0.01)
    assert _confirmed(test(0.01, 0.2, p=0.001), 0.05, 0.01) and not _confirmed(test(0.01, 0.2, p=0.2), 0.05, 0.01)
    assert not _confirmed(test(-0.01, 0.2, p=0.001), 0.05, 0.01)


def test_a_named_term_earns_its_place_only_where_the_effect_is(bag_dirs):
    """Term by term on held-out groups: soil inertia beside side-wall shear earns its place in the soil-inertia
    data (removing it makes the held-out force error worse) and not in the control's; both are judged
    there (their force on the held-out ticks is not negligible)."""
    from soil_discrepancy.fee_fit import fit_fixed
    from soil_discrepancy.frame import build_frame
    from soil_discrepancy.workflow import _place

    model = AugmentedFEE((("soil_inertia", 4.0), ("side_wall_shear", 30.0)))
    for name, where in (("soil_inertia", True), ("control", False)):
        frame = build_frame(blind(bag_dirs[name]), stride=8)
        _, test_groups = split_holdout(frame, 0.3, seed=0)
        ftest = frame.select(groups=test_groups)
        base = fit_fixed(ftest, AugmentedFEE())
        place = _place(ftest, model, "soil_inertia", base, None, 0.05)
        assert place["judged"] and place["earns"] is where and (place["gain"] > 0) is where, (name, place)


def test_a_pinned_form_with_structure_left_in_its_scales_variable_says_the_effect_may_not_scale_so():
    """An outside reader's load-cell drift (150 N/s, the same at every depth) was named w d · τ,
    "pinned down" (the library has no depth-free scale growing with time), with structure left vs
    the cut depth, which the verdict did not tie to the form's scale."""
    from soil_discrepancy.verdict import shape_caveat

    labels = {"d": "cut depth d", "t": "time in episode"}
    reg = {"significant": True, "flagged_variables": ["d"]}
    said = shape_caveat("form:wd_x*tau", {"pinned": True}, reg, labels)
    assert "structure remains vs cut depth d, which its scale w d" in said and "may not scale so" in said, said
    assert "near the form's" in shape_caveat("form:wd_x*tau", {"pinned": True}, {**reg, "flagged_variables": ["t"]}, labels)
    assert shape_caveat("form:one_x*tau", {"pinned": True}, reg, labels) == ""  # a constant scale varies with nothing
    # the model's own force and the pile vary with every motion variable: structure another effect leaves
    # there says nothing of their law (0.15 F_FEE v_x² found in form; the pile's relief −k Q)
    assert shape_caveat("form:fee*vx2", {"pinned": True}, {**reg, "flagged_variables": ["v_z"]}, labels) == ""
    assert shape_caveat("form:-q_x*1", {"pinned": True}, {**reg, "flagged_variables": ["distance"]}, labels) == ""
    assert "which its scale" in shape_caveat("form:mom_x*1", {"pinned": True}, {**reg, "flagged_variables": ["v_x"]}, labels)
    assert shape_caveat("form:wd_x*tau", {"pinned": True}, {**reg, "significant": False}, labels) == ""
    # a form whose factor alone is pinned down: an outside tester's z force acting only above 0.8 m/s was
    # named −γ d² w (v_x / 1 m/s)², "its factor is pinned down", with structure left vs v_x
    factor_only = {"pinned": False, "stand_in": False, "n_better": 0, "few_levels": None, "shape_pinned": False,
                   "factor_pinned": True, "scale_pinned": False}
    labels["v_x"] = "forward speed v_x"
    said = shape_caveat("form:gd2w_z*vx2", factor_only, {**reg, "flagged_variables": ["v_x"]}, labels)
    assert said.startswith("; its factor is pinned down among the library's forms, but structure remains vs forward "
                           "speed v_x"), said
    assert shape_caveat("form:gd2w_z*vx2", factor_only, reg, labels) == ""  # (structure elsewhere: its scale is not pinned)
    assert shape_caveat("form:gd2w_z*vx2", {**factor_only, "factor_pinned": False}, {**reg, "flagged_variables": ["v_x"]},
                        labels) == ""  # nothing pinned: its own words say so
    # travel is seen through the speed: an outside tester's 2 kN drag over the first metre, the same at every
    # depth, was named w d · exp(−s / 0.5 m), "pinned down", with structure left vs v_x alone
    said = shape_caveat("form:wd_x*enter0.5", {"pinned": True}, {**reg, "flagged_variables": ["v_x"]}, labels)
    assert "structure remains vs forward speed v_x with it, through which travel is seen" in said, said
    assert shape_caveat("form:wd_x*enter0.5", {"pinned": True}, {**reg, "flagged_variables": ["v_z"]}, labels) == ""
    assert shape_caveat("form:wd_x*tau", {"pinned": True}, {**reg, "flagged_variables": ["v_x"]}, labels) == ""
    assert shape_caveat("form:wd_x*enter0.5", factor_only, {**reg, "flagged_variables": ["v_x"]}, labels).startswith(
        "; its factor is pinned down among the library's forms, but structure remains vs forward speed v_x with it, "
        "through which travel is seen")
    # the model's force and the pile vary with v_x themselves: structure there may be another effect's
    assert shape_caveat("form:fee*enter0.5", {"pinned": True}, {**reg, "flagged_variables": ["v_x"]}, labels) == ""
    assert shape_caveat("form:-q_x*enter0.5", {"pinned": True}, {**reg, "flagged_variables": ["v_x"]}, labels) == ""
    # a scale that varies with v_x itself says so of its scale
    assert "which its scale" in shape_caveat("form:mom_x*enter0.5", {"pinned": True},
                                             {**reg, "flagged_variables": ["v_x"]}, labels)


def test_the_headline_says_when_no_named_form_is_pinned_down_and_a_tentative_form_says_its_forecast():
    """An outside reader's hidden speed step was "explained" by a momentum flux times v_x², one of five
    forms that fit as well: the headline now says the form is NOT pinned down. And a tentative form
    whose held-out force error fell (1390 -> 901 N) read like a pass: what failed, the force at
    another depth (38.7 -> 62.3 %), is said beside it."""
    from soil_discrepancy.report import headline_verdict
    from soil_discrepancy.verdict import verdict_of

    loose = {"pinned": False, "n_better": 0, "stand_in": False, "shape_pinned": False, "factor_pinned": False,
             "scale_pinned": False, "rivals": [{"name": "form:mom_x*sat2", "share": 0.5}]}
    scale = {**loose, "scale_pinned": True}
    report = {"verdict": "explained", "selection": {"accepted": [{"name": "form:mom_x*vx2", "pin": loose}]}}
    assert headline_verdict(report) == "explained by a form NOT pinned down"
    two = {**report, "selection": {"accepted": [{"name": "form:mom_x*vx2", "pin": loose},
                                                {"name": "form:gd2w_x*vx", "pin": {"pinned": True}}]}}
    assert headline_verdict(two) == "explained" and headline_verdict({**report, "verdict": "unexplained"}) == "unexplained"
    assert headline_verdict({**report, "selection": {"accepted": [{"name": "form:gd2w_x*vx", "pin": scale}]}}) == "explained"
    # a catalogue term whose form the data do not pin down: an outside reader's drag ∝ tan φ · v_x was
    # "explained" by soil inertia (fifteen forms fit as well), by the rate strength with another split
    assert headline_verdict({**report, "selection": {"accepted": [{"name": "soil_inertia", "pin": loose}]}}) == \
        "explained by a term whose form is NOT pinned down"
    assert headline_verdict({**report, "selection": {"accepted": [{"name": "soil_inertia", "pin": {"pinned": True}}]}}) == "explained"
    assert headline_verdict({**report, "selection": {"accepted": [{"name": "soil_inertia", "pin": loose},
                                                                  {"name": "form:mom_x*vx2", "pin": loose}]}}) == \
        "explained by terms whose forms are NOT pinned down"
    reg = {"significant": True, "flagged_variables": ["d"], "misfit": None}
    forms = {"not_confirmed": {"forms": ["form:-gd2w_x*below0.15"], "test_rmse_before": 1390.0, "test_rmse_after": 901.0,
                               "forecast_pct_before": 38.7, "forecast_pct_after": 62.3}}
    verdict, text = verdict_of([], reg, None, forms=forms)
    assert verdict == "unexplained" and "RMSE 1390 -> 901 N, force at another depth 38.7 -> 62.3 % of |F|)" in text
    forms["not_confirmed"]["forecast_pct_after"] = None
    assert "RMSE 1390 -> 901 N)" in verdict_of([], reg, None, forms=forms)[1]


def test_a_weak_unpinned_form_alone_is_at_best_a_partial_explanation():
    """A sensor drift hidden in the fee world was named as a form scaled by the cut's area, not pinned
    down, taking 24 % off the held-out error, and the verdict said "explained": forms alone, not
    pinned down and under a quarter of the held-out error, make "partly explained"."""
    from types import SimpleNamespace

    from soil_discrepancy.verdict import weak_forms_only

    form, other = SimpleNamespace(name="form:wd_x*tsat10"), SimpleNamespace(name="form:one_x*vx")
    beaten = {"pinned": False, "stand_in": False, "n_better": 3, "n_rivals": 9, "share": 0.045,
              "rivals": [{"name": "form:wd_z*enter0.5", "better": True, "share": 0.123}]}
    pinned = {"pinned": True}
    assert weak_forms_only([form], {form.name: beaten}, 0.24)
    assert not weak_forms_only([form], {form.name: beaten}, 0.30)  # a quarter or more: a finding
    assert not weak_forms_only([form], {form.name: pinned}, 0.24)  # pinned down: its form is what the data say
    assert not weak_forms_only([form, other], {form.name: beaten, other.name: pinned}, 0.1)
    assert not weak_forms_only([SimpleNamespace(name="soil_inertia")], {}, 0.1)  # a catalogue mechanism
    assert not weak_forms_only([form], {form.name: beaten}, None) and not weak_forms_only([], {}, 0.1)
    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.verdict import verdict_of

    named = [TermScore(name=form.name, k=0.42, k_se=0.001, k_folds=[0.42] * 5, gain=0.2, p=1e-6)]
    quiet = {"significant": False, "flagged_variables": []}
    test = {"before": {"rmse": 593.0}, "after": {"rmse": 453.0}}
    verdict, text = verdict_of(named, {"significant": True, "flagged_variables": ["t"]}, test, quiet, pins={form.name: beaten})
    assert verdict == "partly explained" and "partly, at best: the named form takes only 24 % off" in text, text
    verdict, text = verdict_of(named, {"significant": True, "flagged_variables": ["t"]}, test, quiet, pins={form.name: pinned})
    assert verdict == "explained" and "at best" not in text, text


def test_a_pinned_form_that_leaves_theta_on_the_soil_tests_bounds_beyond_chance_is_a_possible_stand_in():
    """With soil tests, the effect's mechanism releases θ from the tests' bounds to what chance leaves
    there. An outside tester's drag ∝ √d was named as a constant force "pinned down" and the verdict
    said "explained" while θ stayed on a test's bound in 6 of 12 groups (12 before): fewer than before,
    so the old rule (as many as before) kept quiet. More groups on a bound than chance allows (each
    tested parameter outside its ± 2 std interval 4.6 % of the time) is now a possible stand-in and
    at best a partial explanation; as many as chance leaves is not."""
    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.verdict import bound_hits_by_chance, verdict_of

    def reg(on_bound: int, groups: int = 12, tested: int = 2) -> dict:
        rows = [{"kind": "group", "name": f"g{i}", "tested_parameters": tested,
                 "theta_at_bound": ["c at its soil test's upper bound"] if i < on_bound else []} for i in range(groups)]
        return {"significant": False, "flagged_variables": [], "misfit": {"rows": rows, "alpha": 0.01, "groups": [], "soils": []}}

    named = [TermScore(name="form:one_x*1", k=1.0, k_se=0.015, k_folds=[1.0] * 5, gain=0.68, p=1e-9)]
    test = {"before": {"rmse": 613.0}, "after": {"rmse": 502.0}}
    pins = {"form:one_x*1": {"pinned": True}}
    verdict, text = verdict_of(named, {**reg(12), "significant": True, "flagged_variables": ["d"]}, test, reg(6), pins=pins)
    assert verdict == "partly explained" and "θ stays on a test's bound in 6 groups (12 without the named terms" in text, text
    assert "STAND-INS" in text
    verdict, text = verdict_of(named, {**reg(12), "significant": True, "flagged_variables": ["d"]}, test, reg(1), pins=pins)
    assert verdict == "explained" and "STAND-INS" not in text, text  # one group of twelve: chance
    # the chance itself: none on a bound is certain, all twelve impossible, untested groups never land there
    assert bound_hits_by_chance(reg(0)) == 1.0 and bound_hits_by_chance(reg(12)) < 1e-12
    assert bound_hits_by_chance(reg(1)) == pytest.approx(1 - (1 - 0.0455) ** (2 * 12), rel=1e-3)  # 1 - P(none)
    assert bound_hits_by_chance(reg(1, tested=0)) == 0.0
    # one group on a bound before and after, as chance leaves (a reviewer: the old rule, "as many as
    # before", had called a right term a stand-in there)
    verdict, text = verdict_of(named, {**reg(1), "significant": True, "flagged_variables": ["d"]}, test, reg(1), pins=pins)
    assert verdict == "explained" and "STAND-INS" not in text, text
    # a report written before the rows said how many parameters their tests bound: nothing is claimed
    old = reg(6)
    for r in old["misfit"]["rows"]:
        del r["tested_parameters"]
    assert bound_hits_by_chance(old) == 1.0


def test_a_named_term_that_makes_one_axis_worse_on_the_held_out_episodes_is_said_and_partial():
    """An outside tester's compaction on x only was named as the catalogue's compaction hardening,
    which acts on both axes, "explained": x's held-out mean |error| fell 906 -> 98 N while z's rose
    41 -> 96 N, and nothing said so. Now the verdict says which axis got worse and is at best
    "partly explained" (why: a part of the terms on that axis, or, for terms of the other axis alone,
    the soil refitted beside them); an axis that moves by a few % is left alone."""
    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.verdict import verdict_of

    named = [TermScore(name="compaction_hardening", k=0.0519, k_se=0.0003, k_folds=[0.0519] * 5, gain=0.88, p=1e-12)]
    quiet = {"significant": False, "flagged_variables": []}
    before = {"rmse": 1293.2, "rmse_x": 1274.1, "rmse_z": 221.4, "mae_x": 906.2, "mae_z": 41.4}
    worse_z = {"before": before, "after": {"rmse": 513.6, "rmse_x": 457.4, "rmse_z": 233.6, "mae_x": 97.7, "mae_z": 96.2}}
    verdict, text = verdict_of(named, {"significant": True, "flagged_variables": ["t"]}, worse_z, quiet)
    assert verdict == "partly explained", text
    assert "but the held-out z error rises (RMSE 221 -> 234 N, mean |error| 41 -> 96 N): the named terms' z part is " \
           "not in the data" in text, text
    # a form of x alone has no z part to blame (an eighth reader's): the soil refitted beside it moved z
    for name in ("form:gd2w_x*vx2", "soil_inertia"):  # a form and a catalogue term of x alone
        x_only = [TermScore(name=name, k=0.49, k_se=0.06, k_folds=[0.49] * 5, gain=0.5, p=1e-9)]
        text = verdict_of(x_only, {"significant": True, "flagged_variables": ["t"]}, worse_z, quiet)[1]
        assert "the named terms have no z part, so the soil refitted beside them moved z" in text, text
    same_z = {"before": before, "after": {**worse_z["after"], "rmse_z": 223.0, "mae_z": 42.5}}
    verdict, text = verdict_of(named, {"significant": True, "flagged_variables": ["t"]}, same_z, quiet)
    assert verdict == "explained" and "error rises" not in text, text


def test_a_catalogue_term_given_with_accepted_is_not_said_to_be_tested():
    """A term of the user's catalogue also given with --accepted is in the model from the start:
    the report said it was "tested as a candidate ... not named" (an outside tester found)."""
    import json
    from pathlib import Path

    from soil_discrepancy.report import markdown

    report = json.loads((Path(__file__).parents[2] / "docs/discrepancy/control/discrepancy.json").read_text())
    report["settings"]["user_terms"] = {"soil_inertia": "my inertia", "rate_strength": "mine"}
    report["settings"]["accepted_initial"] = [["soil_inertia", 2.0]]
    (line,) = [ln for ln in markdown(report).splitlines() if "your catalogue" in ln]
    assert "'my inertia' (`soil_inertia`): in the model from the start (`--accepted`), not tested" in line
    assert "'mine' (`rate_strength`): not named" in line


def test_a_named_form_whose_formula_holds_pipes_keeps_the_reports_tables_whole():
    """A discovered form's formula may hold |v_z| and a group name anything: each stays one cell
    (a '|' unescaped split the row, and the reader showed the formula's tail as the k column)."""
    import json
    from pathlib import Path

    from soil_discrepancy.index import index_markdown
    from soil_discrepancy.report import markdown
    from soil_msgs_py.markdown_table import malformed_rows
    from soil_physics import term_forms

    report = json.loads((Path(__file__).parents[2] / "docs/discrepancy/compaction/discrepancy.json").read_text())
    name = "form:fee*still"
    formula = term_forms.describe(name)["formula"]
    assert "|" in formula
    report["selection"]["accepted"][0].update(name=name, title="a still blade's grip", formula=formula)
    report["selection"]["rounds"][0]["scores"][0]["name"] = name
    text = markdown(report)
    assert malformed_rows(text) == []
    assert formula.replace("|", "\\|") in text

    def renamed(x):  # every soil named Sand a user's "Sand|wet": groups, regime bins, misfit rows, the PINN's
        if isinstance(x, dict):
            return {k: renamed(v) for k, v in x.items()}
        if isinstance(x, list):
            return [renamed(v) for v in x]
        return x.replace("Sand", "Sand|wet") if isinstance(x, str) else x

    for case in ("compaction", "default_world"):  # (the unlabelled case's groups are unit weights)
        wet = renamed(json.loads((Path(__file__).parents[2] / f"docs/discrepancy/{case}/discrepancy.json").read_text()))
        text = markdown(wet)
        assert "Sand\\|wet" in text and malformed_rows(text) == [], (case, malformed_rows(text))
    assert malformed_rows(index_markdown(Path(__file__).parents[2] / "docs/discrepancy")) == []


@pytest.mark.timeout(300)
def test_pinn_workers_that_cannot_start_are_said_not_waited_for(tmp_path):
    """A script calling pinn_gap with workers at its top level (no ``if __name__ == "__main__":``)
    runs again in each spawned worker, which then fails as it starts. The parent wrote the dataset
    down the worker's start pipe and waited there for ever (a user's script idle ten minutes). It
    goes through a file now: the script ends at once with the dead worker said, and Python's
    reason above it."""
    script = tmp_path / "unguarded.py"
    script.write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(Path(__file__).resolve().parents[2])!r})\n"
        "from soil_discrepancy.candidates import split_holdout\n"
        "from soil_discrepancy.frame import build_frame\n"
        "from soil_discrepancy.pinn_check import pinn_gap\n"
        "from soil_physics.augmented_fee import AugmentedFEE\n"
        "from tests.soil_discrepancy.test_discrepancy import simulated, small_grid\n"
        "ds = simulated(small_grid()[::2])\n"
        "frame = build_frame(ds, stride=8)\n"
        "sel, held = split_holdout(frame, 0.3, 0)\n"
        "pinn_gap(ds, frame.select(groups=held), frame.episode_names(sel), AugmentedFEE(), AugmentedFEE(),\n"
        "         epochs=1, seed=0, seeds=1, stride=8, eval_stride=20, log=None, threads=1, workers=2)\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert out.returncode != 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "WorkerDied: a worker process died while training PINNs" in out.stderr, out.stderr[-3000:]
    assert "bootstrapping phase" in out.stderr, out.stderr[-3000:]  # (Python's own reason, from the worker)


def test_copies_of_an_episode_are_analysed_once():
    """The noise-free fee world's seeds of one grid point are one episode: analysed as many, their
    evidence counted as many times (an outside tester's grid of two seeds named a speed effect on one
    target speed, its paired test over 16 episodes of 8). Left out but one, and said; a world whose
    seeds differ (its noise) keeps them all."""
    from soil_discrepancy.workflow import _left_out

    specs = grid_specs(["Sand", "Clay"], [50.0], [0.5], [0.1, 0.2], 2, seed_base=0, duration_s=4.0)
    frame = build_frame(simulated(specs), stride=8)
    assert len(frame.copies) == 4 and len(frame.episodes) == 4, frame.copies
    analysed = {frame.names[e] for e in frame.episodes}
    assert not analysed & set(frame.copies) and {n.rsplit("_s", 1)[0] for n in analysed} == \
        {n.rsplit("_s", 1)[0] for n in frame.copies}  # one of each grid point stays
    assert any(names == frame.copies and "a copy of another episode" in why for names, why in _left_out(frame))
    noisy = build_frame(simulated(specs, mode="default"), stride=8)
    assert noisy.copies == () and len(noisy.episodes) == 8
