"""Missing physics whose form is not in the catalogue: found by the library search, or left unexplained.

Hidden effects written as simulator plugins (tests/sim_plugins.py), on the 32-episode fee-world
grid of test_discrepancy.py (every 8th tick; simulated in this process, the entry drag's also as bags for the CLI):

* entry_resistance: F_x = 2 γ w d² exp(−s / 1 m), extra drag of undisturbed soil fading with the
  blade's travel (not a library form: its decay lengths are 0.5 m and 2 m);
* saturating_drag: F_x = w d · 10 kPa · tanh(v_x / 0.3 m/s), where the catalogue offers only a drag
  linear in v_x (rate_strength), which also shrinks the error: the form must beat it;
* sinking_resistance: F_z = −3 γ w d² · min(max(−v_z, 0)/0.01 m/s, 1), only while the edge sinks
  (the library's gate is a hard one at 5 mm/s). The resisting force slows the sinking it depends
  on, so the measured force follows the gate loosely and the held-out gain is small: with a
  higher least gain the form stays tentative and the verdict "unexplained".
* time_drag: F_x = w d · 10 kPa · min(t / 10 s, 1), a drag that grows with time, not with travel:
  on time in soil, which the library has beside travel (two speeds tell them apart).

The workflow never sees the plugins (``blind``). Expected: the right scale, axis and factor or gate,
a held-out error that shrinks, no catalogue name.
"""
from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from soil_discrepancy import run_discrepancy
from soil_discrepancy.forms import CLOSE_COS, closest_index, load_catalogue, pin_kind
from soil_physics import force_terms, term_forms
from soil_physics.augmented_fee import AugmentedFEE
from soil_physics.force_inputs import ForceInputs
from soil_physics.soils import CATALOGUE as SOILS
from soil_sim_node.batch import DatasetPlan, generate, grid_specs
from soil_sim_node.effects import Effects, effects_for_mode, load_plugins

from .test_discrepancy import RUN, blind, named_verdict, simulated, small_grid

HIDDEN = {
    "entry": ("tests.sim_plugins:entry_resistance k=2 s0=1",),
    "saturating": ("tests.sim_plugins:saturating_drag k=1 v0=0.3",),
    "sinking": ("tests.sim_plugins:sinking_resistance k=3",),
    "time": ("tests.sim_plugins:time_drag k=1",),
}
STRIDE = 8


@pytest.fixture(scope="module")
def entry_bags(tmp_path_factory) -> Path:
    """The entry drag's episodes as bags (the CLI reads them)."""
    root = tmp_path_factory.mktemp("forms") / "entry"
    generate(DatasetPlan("fee", root, small_grid(), effects_for_mode("fee"), plugins=HIDDEN["entry"]), workers=2,
             progress=False)
    return root


@pytest.fixture(scope="module")
def form_data(entry_bags) -> dict:
    """Each hidden form's episodes, blind: the entry drag's read from its bags, the others simulated."""
    return {name: blind(entry_bags) if name == "entry" else simulated(small_grid(), plugins)
            for name, plugins in HIDDEN.items()}


@pytest.fixture(scope="module")
def form_reports(form_data, tmp_path_factory) -> dict[str, dict]:
    return {name: run_discrepancy(dataset=form_data[name], out_dir=tmp_path_factory.mktemp(name), plots=False,
                                  **{**RUN, "stride": STRIDE})
            for name in ("entry", "saturating", "time")}


def test_entry_drag_is_found_with_its_form_and_shrinks_the_heldout_error(form_reports):
    rep = form_reports["entry"]
    assert rep["selection"]["accepted"] and rep["verdict"] == named_verdict(rep), rep["summary"]
    accepted = rep["selection"]["accepted"]
    assert not [a for a in accepted if a["name"] in force_terms.CATALOGUE], "no catalogue name for a form it lacks"
    first = accepted[0]
    sign, scale, factor = term_forms.parse(first["name"])
    # the right scale and axis (γ d² w in x, a resistance) and the right factor (fading with travel)
    assert (sign, scale.name) == (1.0, "gd2w_x") and factor.name.startswith("enter"), first["name"]
    assert first["k"] > 0 and first["k_se"] < 0.2 * first["k"] and first["p_holm"] < 0.01
    test = rep["test"]
    assert test["after"]["rmse"] <= 0.75 * test["before"]["rmse"], (test["before"], test["after"])
    assert test["after"]["rmse_x"] < test["before"]["rmse_x"]
    # the report: formula, regimes where it acts, closest catalogue term (not the same mechanism)
    disc = rep["forms"]["discovered"][0]
    assert disc["name"] == first["name"] and disc["axis"] == "x"
    assert not disc["closest_catalogue"]["same_mechanism"]
    assert 0.9 < disc["regime"]["share_of_ticks"] <= 1.0 and disc["regime"]["ranges"]["distance"][0] < 1.0
    # these data pin its shape down, fading with travel: in its place every other form fits what it
    # takes worse, but the hidden 1 m lies between the library's 0.5 m and 2 m, which 22 selection
    # episodes (two speeds) cannot tell apart
    pin = disc["pin"]
    assert pin["pinned"] or (pin["shape_pinned"] and all("*enter" in r["name"] for r in pin["rivals"])), pin
    out = Path(rep["outputs"][0]).parent  # discrepancy.json
    md = (out / "discrepancy.md").read_text()
    assert "## Form search" in md and "### Discovered:" in md and "exp(−s /" in md
    assert "Pinned down by these data?" in md
    saved = json.loads((out / "discrepancy.json").read_text())
    assert saved["forms"]["discovered"][0]["name"] == first["name"]
    # saved as the user's own catalogue, which the next run reads (a bad one is refused by name)
    (row,) = load_catalogue(out / "discovered_terms.yaml")
    assert row["term"] == first["name"] and row["k"] == pytest.approx(first["k"])
    bad = out / "bad.yaml"
    bad.write_text("terms:\n- term: form:gd2w_x*nope\n")
    with pytest.raises(ValueError, match=r"terms\[0\].*nope"):
        load_catalogue(bad)
    # a discovered form is a term like a catalogue term: the model and the simulator plugin take it
    spec = rep["model"]["plugin_specs"][0]
    assert load_plugins([spec])[0].params["term"] == first["name"]
    AugmentedFEE(rep["model"]["extra_term_args"])


def test_a_term_of_the_users_catalogue_is_tested_and_said_under_the_users_name(entry_bags, form_reports, tmp_path):
    """The saved catalogue says "rename 'name' as you like": the next run tests the term and its
    report says it under that name (and records the catalogue's terms and names)."""
    from soil_discrepancy.cli import main as cli_main

    form = form_reports["entry"]["selection"]["accepted"][0]["name"]
    mine = tmp_path / "mine.yaml"
    mine.write_text(f"terms:\n- term: {form}\n  name: my entry drag\n")
    out = tmp_path / "o"
    assert cli_main([str(entry_bags), "--out", str(out), "--catalogue", str(mine), "--stride", "8",
                     "--no-forms", "--no-plots", "--quiet", "--workers", "2"]) == 0
    rep = json.loads((out / "discrepancy.json").read_text())
    assert rep["settings"]["user_terms"] == {form: "my entry drag"} and form in rep["settings"]["candidates"]
    # the JSON keeps the headline's hedge beside the verdict's class, for scripts
    from soil_discrepancy.report import headline_verdict
    assert rep["headline"] == headline_verdict(rep) and rep["headline"].startswith(rep["verdict"])
    named = form in {a["name"] for a in rep["selection"]["accepted"]}
    said = f"'my entry drag' (`{form}`): " + ("**named**" if named else "not named")
    assert said in (out / "discrepancy.md").read_text()
    # re-simulated in the bags' world (the report said --mode fee whatever the world)
    from soil_discrepancy.report import markdown

    assert "soil_sim_batch --mode fee --out bags/with_effect" in (out / "discrepancy.md").read_text()
    assert "soil_sim_batch --mode default --out bags/with_effect" in markdown({**rep, "data": {**rep["data"], "world": ""}})
    if named:  # the verdict calls it by the user's name too (it had said only the formula)
        assert f"'my entry drag', the form {force_terms.get_term(form).formula} ({form})" in rep["summary"]


def test_speed_saturating_drag_is_found_and_beats_the_linear_catalogue_drag(form_reports):
    rep = form_reports["saturating"]
    assert rep["selection"]["accepted"] and rep["verdict"] == named_verdict(rep), rep["summary"]
    (acc,) = rep["selection"]["accepted"]
    info = term_forms.describe(acc["name"])
    # a drag growing with speed and saturating: tanh(v_x/v0), or minus a fading exp(−v_x/v0) beside
    # the constant θ takes (at this grid's two speeds any function of speed is affine in another)
    saturating = info["factor"].startswith("tanhvx") and info["sign"] > 0
    fading_relief = info["factor"].startswith("fadevx") and info["sign"] < 0
    assert info["axis"] == "x" and (saturating or fading_relief), acc["name"]
    assert info["scale"] in ("wd_x", "gd2w_x", "bear_x"), acc["name"]
    # the catalogue's linear drag was in the same round and lost on held-out groups
    first = rep["selection"]["rounds"][0]
    gains = {s["name"]: s["gain"] for s in first["scores"]}
    assert first["winner"] == acc["name"] and gains["rate_strength"] < gains[acc["name"]]
    test = rep["test"]
    assert test["after"]["rmse"] <= 0.75 * test["before"]["rmse"], (test["before"], test["after"])
    # two speeds pin no factor of speed (k, θ and a characteristic value match any at two levels; an
    # outside tester's 0.3 / v_x drag was "explained" as exp(−v_x / 0.3 m/s), "its shape pinned
    # down"): never called pinned down, and the summary says why
    pin = next(d["pin"] for d in rep["forms"]["discovered"] if d["name"] == acc["name"])
    assert pin["few_levels"]["variable"] == "v_x" and len(pin["few_levels"]["levels"]) == 2, pin
    assert not pin["pinned"] and not pin["shape_pinned"] and not pin["factor_pinned"], pin
    assert pin_kind(pin) in ("levels", "form", "beaten", "stand-in") and "v_x takes values in only 2 group(s)" in rep["summary"]


def test_a_drag_growing_with_time_is_found_on_time_in_soil_not_on_travel(form_reports):
    """Time in soil and travel differ by the speed (s = ∫ v_x dt): with two speeds the search takes
    time, and nothing on travel (a form or the catalogue's compaction hardening) is named for it."""
    rep = form_reports["time"]
    assert rep["selection"]["accepted"] and rep["verdict"] == named_verdict(rep), rep["summary"]
    (acc,) = rep["selection"]["accepted"]
    info = term_forms.describe(acc["name"])
    assert info["axis"] == "x" and info["sign"] > 0 and info["factor"] in term_forms.TIME_FACTORS, acc["name"]
    assert info["scale"] == "wd_x" and acc["k"] == pytest.approx(1.0, rel=0.1)  # w d · 10 kPa · τ / 10 s: the hidden one
    assert not force_terms.uses_distance(acc["name"]) and force_terms.uses_time(acc["name"])
    test = rep["test"]
    assert test["after"]["rmse"] <= 0.5 * test["before"]["rmse"], (test["before"], test["after"])
    # a first-class term: the model asks for the time in soil, the simulator plugin and the PINN take it
    model = AugmentedFEE(rep["model"]["extra_term_args"])
    assert model.needs_time
    with pytest.raises(ValueError, match="time in soil"):
        model.force((0.5, 1e3, 0.3), np.array([[0, 17e3, 1.0, 0, 3.0, 0.2, 0, 0.5, 0]]), [1.0])
    assert load_plugins(rep["model"]["plugin_specs"])[0].params["term"] == acc["name"]
    assert "τ / 10 s" in rep["forms"]["discovered"][0]["formula"]
    md = (Path(rep["outputs"][0]).parent / "discrepancy.md").read_text()
    assert re.search(r"time in soil τ [\d.]+…[\d.]+", md), "where it acts, by name"


def test_sinking_only_force_gets_its_gate_and_is_not_named_unless_the_test_confirms_it(form_data, tmp_path):
    """min_gain 0.2: the gated form removes ~1/3 of the cross-validated error but only ~11 % of the held-out
    test episodes' (seed 0, measured on every 4th tick): a tentative form, not a name; the verdict stays 'unexplained' with its regimes."""
    rep = run_discrepancy(dataset=form_data["sinking"], out_dir=tmp_path, plots=False,
                          **{**RUN, "stride": STRIDE, "min_gain": 0.2})
    top = term_forms.describe(rep["forms"]["search"]["candidates"][0])
    # z, pressing down (k > 0 on a downward scale), gated by the edge sinking
    assert top["axis"] == "z" and top["factor"] in ("sink", "sinkv") and top["sign"] > 0, rep["forms"]["search"]
    assert rep["forms"]["search"]["ols"][0]["t"] > 3
    assert not [a for a in rep["selection"]["accepted"] if a["name"] in force_terms.CATALOGUE]
    tentative = rep["forms"]["not_confirmed"]
    if tentative is None:  # the held-out episodes confirmed it: then it is the gated z form
        (acc,) = rep["selection"]["accepted"]
        assert term_forms.describe(acc["name"])["factor"] in ("sink", "sinkv")
        return
    assert rep["verdict"] == "unexplained" and rep["model"]["terms"] == [] and "v_z" in rep["regimes"]["flagged_variables"]
    assert tentative["forms"] == [d["name"] for d in rep["forms"]["discovered"]] and "tentative" in rep["summary"]
    assert "NOT confirmed" in (tmp_path / "discrepancy.md").read_text()
    assert not (tmp_path / "discovered_terms.yaml").exists()


def test_a_pile_that_pushes_less_than_the_model_says_is_a_relief_not_surcharge_drag(tmp_path):
    """The world's FEE takes a tenth of the pile's Q N_Q (the default world's surcharge alone, every
    other effect off), the model all of it: the residual is −0.9 (F_FEE(Q) − F_FEE(0)), less force
    where the catalogue's ``surcharge_drag`` (+k Q in x, k >= 0) has more. Before, the search dropped
    the −Q forms as "that term", which cannot take k < 0, and named two stand-ins (a constant
    4.2 kN · tanh(v_x / 0.3 m/s) and Q growing with time in soil; 1672 -> 497 N held out, structure
    left vs Q). Now the pile's weight as a relief, the catalogue term its opposite, never its name."""
    off = {name: False for name in Effects.names() if name != "surcharge"}
    specs = small_grid()
    pile = simulated(specs, mode="default", effects=effects_for_mode("default").with_switches(**off))
    rep = run_discrepancy(dataset=pile, out_dir=tmp_path / "out", plots=False,
                          **{**RUN, "stride": STRIDE})
    assert rep["selection"]["accepted"] and rep["verdict"] == named_verdict(rep), rep["summary"]
    accepted = rep["selection"]["accepted"]
    assert not [a for a in accepted if a["name"] in force_terms.CATALOGUE], accepted
    sign, scale, factor = term_forms.parse(accepted[0]["name"])
    assert sign < 0 and scale.name in ("q_x", "qnq") and factor.name == "1", accepted[0]["name"]  # −k Q (N_Q)
    close = rep["forms"]["discovered"][0]["closest_catalogue"]
    assert close["name"] == "surcharge_drag" and close["opposite"] and not close["same_mechanism"], close
    assert rep["test"]["after"]["rmse"] <= 0.35 * rep["test"]["before"]["rmse"], rep["test"]  # 1672 -> 420 N
    md = (tmp_path / "out" / "discrepancy.md").read_text()
    assert "acts against that term's physics" in md and "surcharge_drag in another form" not in md


def test_a_pinned_form_leaving_structure_in_its_own_variable_is_called_the_nearest_shape():
    """A drag growing linearly with travel up to a cap was named 1 − exp(−s / 2 m), "pinned down" (the
    library's best), k 1.8 for 1.5, with structure left vs distance: now the verdict says its shape
    there is the nearest one's. Not where the structure is elsewhere, nor beside a form not pinned
    down (its caveat says more), a catalogue term, or no structure at all."""
    from soil_discrepancy.regimes import variable_labels
    from soil_discrepancy.verdict import shape_caveat
    from soil_physics.term_forms import FACTORS, factor_variable

    assert [factor_variable(f) for f in ("sat2", "enter0.5", "s", "tsat10", "tau", "d", "below0.15", "fadevx0.3",
                                         "vx2", "tanhvz0.05", "sinkv", "1", "xlim")] == \
        ["distance", "distance", "distance", "t", "t", "d", "d", "v_x", "v_x", "v_z", "v_z", None, None]
    assert all(factor_variable(f) in (None, "d", "v_x", "v_z", "distance", "t") for f in FACTORS)
    labels = variable_labels()
    pinned, loose = {"pinned": True, "rivals": []}, None
    after = {"significant": True, "flagged_variables": ["d", "distance"]}
    text = shape_caveat("form:wd_x*sat2", pinned, after, labels)
    assert text.startswith("; pinned down among the library's forms, but structure remains vs distance cut in soil"), text
    # its factor's variable is time, clean there; its scale w d varies with the depth, where structure is left
    assert "vs cut depth d, which its scale" in shape_caveat("form:wd_x*tsat10", pinned, after, labels)
    assert shape_caveat("form:wd_x*tsat10", pinned, {**after, "flagged_variables": ["v_x", "distance"]}, labels) == ""
    assert shape_caveat("form:wd_x*sat2", pinned, {"significant": False, "flagged_variables": []}, labels) == ""
    assert shape_caveat("form:wd_x*sat2", loose, after, labels) == ""
    assert shape_caveat("soil_inertia", pinned, after, labels) == ""


def test_a_scale_and_a_factor_of_one_variable_are_not_pinned_down_apart():
    """A speed step's drag (w d · 5 kPa above 0.75 m/s, an outside reader's hidden effect) was named
    (γ/g) w d v_x² · (v_x / 1 m/s)² with "its scale is pinned down": every rival kept the momentum
    flux because no other scale carries v_x, so what the data pinned was the steep speed law of
    scale and factor together. Such a pair is not separable; γ d² w · v_x (a viscous wedge drag,
    found so) is, and keeps its claim."""
    from soil_physics.term_forms import FACTORS, SCALE_VARIABLES, SCALES, factor_variable, separable

    assert set(SCALE_VARIABLES) == set(SCALES)
    assert all(v in ("d", "v_x", "v_z", "distance", "t") for vs in SCALE_VARIABLES.values() for v in vs)
    speed = [f for f in FACTORS if factor_variable(f) == "v_x"]
    assert speed and not any(separable("mom_x", f) for f in speed)
    assert all(separable("gd2w_x", f) for f in speed) and separable("one_x", "tanhvx0.3")
    assert not separable("wd_x", "below0.15") and not separable("q_x", "sat2") and separable("q_x", "d")
    assert not any(separable("feex", f) for f in FACTORS if factor_variable(f)) and separable("feex", "xlim")


def test_form_names_parse_and_act_like_catalogue_terms():
    names = term_forms.form_names()
    assert 100 < len(names) <= 500 and len(set(names)) == len(names)
    t = force_terms.get_term("form:-gd2w_z*sink")
    assert term_forms.negated("form:-gd2w_z*sink") == "form:gd2w_z*sink" and "[v_z < " in t.formula
    n = 5
    s = ForceInputs(d=np.full(n, 0.2), q=np.zeros(n), v_x=np.full(n, 0.5), v_z=np.array([-0.1, -0.001, 0.0, 0.01, -0.02]),
                    gamma=np.full(n, 18e3), w=np.full(n, 3.0), rho=np.full(n, 1.4), alpha=np.zeros(n),
                    phi=np.full(n, 0.6), c=np.full(n, 2e3), delta=np.full(n, 0.3), distance_in_soil=np.zeros(n),
                    f_fee_x=np.full(n, 1e4), f_fee_z=np.full(n, -5e3))
    bx, bz = force_terms.plugin(s, "form:gd2w_z*sink", 2.0)
    np.testing.assert_allclose(bx, 0.0)
    np.testing.assert_allclose(bz, -2.0 * 18e3 * 0.04 * 3.0 * np.array([1, 0, 0, 0, 1]))
    fx, fz = force_terms.get_term("form:fee*vx").basis(s)
    np.testing.assert_allclose(fx, 1e4 * 0.5) and np.testing.assert_allclose(fz, -5e3 * 0.5)
    # the signed vertical speed: one column against the edge's motion either way (odd in v_z), 0 out of the soil
    fx, fz = force_terms.get_term("form:-wd_z*vz").basis(s)
    np.testing.assert_allclose(fx, 0.0) and np.testing.assert_allclose(fz, 3.0 * 0.2 * 1e4 * s.v_z / 0.05)
    _, fz = force_terms.get_term("form:-wd_z*tanhvz0.05").basis(replace(s, d=np.array([0.2, 0.2, -0.01, 0.2, 0.2])))
    np.testing.assert_allclose(fz, 3.0 * np.clip([0.2, 0.2, 0, 0.2, 0.2], 0, None) * 1e4 * np.tanh(s.v_z / 0.05))
    # the constant scale: 1 kN while in soil, here as Coulomb friction (saturating with v_x); in the
    # library only as a constant, viscous, Coulomb or Stribeck force, not with the geometry's factors or gates
    assert {n for n in names if "one_x" in n} == {f"form:one_x*{f}" for f in term_forms.CONSTANT_SCALE_FACTORS}
    assert "form:one_x*below0.1" not in names and force_terms.get_term("form:one_x*below0.1")
    fx, fz = force_terms.get_term("form:one_x*tanhvx0.1").basis(replace(s, d=np.array([0.2, 0.2, -0.01, 0.2, 0.2])))
    np.testing.assert_allclose(fx, 1e3 * np.tanh(5.0) * np.array([1, 1, 0, 1, 1])) and np.testing.assert_allclose(fz, 0.0)
    # a form on time in soil needs it, and says so
    with pytest.raises(ValueError, match="time in soil"):
        force_terms.get_term("form:wd_x*tsat3").basis(s)
    fx, _ = force_terms.get_term("form:wd_x*tsat3").basis(replace(s, time_in_soil=np.full(n, 3.0)))
    np.testing.assert_allclose(fx, 3.0 * 0.2 * 1e4 * (1 - np.exp(-1.0)))
    for bad in ("form:gd2w_z", "form:nope*sink", "form:gd2w_z*nope", "gd2w_z*sink"):
        with pytest.raises(ValueError):
            force_terms.get_term(bad)


def test_a_form_is_a_pinn_extra_term_with_gradients_and_asks_for_the_travel_it_uses():
    import torch

    from pinn_estimator.model import ModelConfig

    assert ModelConfig(kind="pinn", extra_terms=("form:gd2w_x*enter2=1.4",)).needs_distance
    assert not ModelConfig(kind="pinn", extra_terms=("form:bear_z*sink=0.4",)).needs_distance
    assert term_forms.DISTANCE_FACTORS == {"s", "enter0.5", "enter2", "sat2", "sat6"}
    assert term_forms.TIME_FACTORS == {"tau", "tenter1", "tenter3", "tsat3", "tsat10"} and not term_forms.TIME_FACTORS & term_forms.DISTANCE_FACTORS
    n = 3
    t = lambda v: torch.full((n,), float(v), dtype=torch.float64)  # noqa: E731
    phi = t(0.6).requires_grad_()
    s = ForceInputs(d=t(0.2), q=t(2e3), v_x=t(0.5), v_z=torch.tensor([-0.1, 0.0, 0.01], dtype=torch.float64),
                    gamma=t(18e3), w=t(3.0), rho=t(1.4), alpha=t(0.0), phi=phi, c=t(2e3), delta=t(0.3),
                    distance_in_soil=t(1.0), f_fee_x=t(1e4), f_fee_z=t(-5e3), c_a=t(0.0))
    total = sum(sum(force_terms.get_term(name).basis(s)) for name in ("form:bear_z*sink", "form:-qnq*1"))
    total.sum().backward()
    assert torch.isfinite(phi.grad).all() and (phi.grad != 0).all()


def test_two_catalogue_effects_at_once_are_named_not_the_one_form_that_mimics_both(tmp_path):
    """Soil inertia and compaction hidden together: greedy selection took one form that mimics both
    (inertia growing with time in soil, `form:mom_x*tsat3`: 83 % off the cross-validated error
    against soil inertia's 74 %; measured on every 6th tick), after which neither catalogue term passed. A
    form is for what the catalogue's mechanisms cannot explain together: their own path (there 88 % off with two terms)
    is taken, both are named first, and the report keeps the path not taken."""
    specs = small_grid()
    two = simulated(specs, ("soil_physics.force_terms:plugin term=soil_inertia k=3",
                            "soil_physics.force_terms:plugin term=compaction_hardening k=0.05"))
    rep = run_discrepancy(dataset=two, out_dir=tmp_path / "out", plots=False,
                          **{**RUN, "stride": STRIDE})
    path = rep["forms"]["catalogue_path"]
    assert path["chosen"] == "catalogue" and path["forms_path"][0].startswith("form:"), path
    assert path["catalogue_left"] <= path["forms_left"], path
    names = [a["name"] for a in rep["selection"]["accepted"]]
    assert set(names[:2]) == {"soil_inertia", "compaction_hardening"}, rep["summary"]
    assert rep["test"]["after"]["rmse"] <= 0.5 * rep["test"]["before"]["rmse"], rep["test"]
    stages = [r["stage"] for r in rep["selection"]["rounds"]]
    assert stages[0].startswith("catalogue + forms: not taken") and "catalogue alone: taken" in stages, stages
    md = (tmp_path / "out" / "discrepancy.md").read_text()
    assert "the catalogue's path is taken" in md and path["forms_path"][0] in md


def test_a_catalogue_term_the_heldout_episodes_refute_is_tentative_and_never_the_verdict(tmp_path):
    """A drag only below 0.2 m (tests/sim_plugins.deep_drag), at the full-size grid of `make
    discrepancy` (108 episodes): cross-validation on the selection groups picks the catalogue's
    side-wall shear (it grows with depth), but on the held-out groups it makes the force error
    worse. A name the held-out test does not confirm is not a name: the verdict is 'unexplained'
    with the regime (depth), the term listed as tentative, no model, no plugin (the catalogue
    search alone here; forms have their own tests above)."""
    specs = grid_specs(list(SOILS), [0.0, 40.0, 80.0], [0.3, 0.65, 1.0], [0.1, 0.175, 0.25], 1, seed_base=100,
                       duration_s=10.0)
    deep = simulated(specs, ("tests.sim_plugins:deep_drag k=3",))
    rep = run_discrepancy(dataset=deep, out_dir=tmp_path / "out", plots=False, forms=False,
                          **{**RUN, "stride": 8})
    tentative = rep["selection"]["not_confirmed"]
    assert tentative is not None and tentative["terms"], rep["summary"]
    # the held-out episodes did not confirm it: the force error did not shrink by the least gain
    assert tentative["sse_reduction"] < 0.05 and tentative["test_rmse_after"] > 0.95 * tentative["test_rmse_before"]
    assert rep["verdict"] == "unexplained" and "d" in rep["regimes"]["flagged_variables"], rep["summary"]
    assert all(t["name"] in force_terms.CATALOGUE for t in tentative["terms"]), tentative["terms"]  # side-wall shear here
    assert rep["selection"]["accepted"] == [] and rep["model"]["terms"] == [] and rep["model"]["plugin_specs"] == []
    assert all(t["name"] in rep["summary"] for t in tentative["terms"]) and "NOT confirmed" in rep["summary"]
    assert rep["test"]["after"]["rmse"] == rep["test"]["before"]["rmse"]  # nothing named, nothing changed
    md = (tmp_path / "out" / "discrepancy.md").read_text()
    assert "## Tentative: NOT confirmed" in md and "## The missing effect" not in md


def _found_exactly(tmp_path, specs, plugin: str, form: tuple[str, str], k: float, pinned: bool = True,
                   sign: float = 1.0) -> dict:
    """A hidden form (``plugin``, a tests/sim_plugins spec) on ``specs`` is named as the library's
    ``form`` = (scale, factor) with ``sign`` (−1: the name's '-') and k within 15 % of ``k``, no catalogue term beside it, and the
    held-out error shrinks by at least a quarter; ``pinned``: no other form fits as well (the report's
    rival check). Returns the discovered form's entry."""
    rep = run_discrepancy(dataset=simulated(specs, (plugin,)), out_dir=tmp_path / "out", plots=False,
                          **{**RUN, "stride": STRIDE})
    assert rep["selection"]["accepted"] and rep["verdict"] == named_verdict(rep), rep["summary"]
    accepted = rep["selection"]["accepted"]
    assert not [a for a in accepted if a["name"] in force_terms.CATALOGUE], accepted
    info = term_forms.describe(accepted[0]["name"])
    assert (info["scale"], info["factor"], info["sign"]) == (*form, sign), accepted[0]["name"]
    assert 0.85 * k < accepted[0]["k"] < 1.15 * k, accepted[0]
    disc = rep["forms"]["discovered"][0]
    assert disc["pin"]["pinned"] == pinned and ("pinned down" in rep["summary"]) != pinned, disc["pin"]
    assert "STAND-IN" not in rep["summary"]
    test = rep["test"]
    assert test["after"]["rmse"] <= 0.75 * test["before"]["rmse"], (test["before"], test["after"])
    return disc


def test_a_layer_below_a_depth_is_found_with_its_top(tmp_path):
    """A harder layer below 0.15 m (tests/sim_plugins.layer_drag: F_x = 6 w (d − 0.15 m)+ 10 kPa), on
    24 episodes at three depths (0.1 m stays above it): the search finds the form itself, w d · 10 kPa
    times the share of the cut below 0.15 m, with its k, and the held-out error shrinks."""
    specs = grid_specs(list(SOILS), [20.0, 80.0], [0.65], [0.1, 0.175, 0.25], 1, seed_base=0, duration_s=10.0)
    _found_exactly(tmp_path, specs, "tests.sim_plugins:layer_drag k=6 d0=0.15", ("wd_x", "below0.15"), 6.0)


def test_a_strength_lost_with_speed_is_found_with_its_decay(tmp_path):
    """Rate weakening (tests/sim_plugins.speed_weakening: F_x = 2 γ w d² exp(−v_x / 0.3 m/s)), on
    24 episodes at three speeds and one depth: a drag that fades with speed, which a saturating form
    could follow only as a relief growing with speed beside a share θ takes, and not closely
    (between 0.3, 0.65 and 1 m/s the decay falls off faster than tanh(v_x/1 m/s), slower than
    tanh(v_x/0.3 m/s)); the search names the decay itself, with its speed scale and k, and the
    held-out error shrinks. At one depth its scale is not pinned down (γ d² w, w d and a constant
    differ only by a soil's γ, which θ takes), and the report says so, naming the same decay on
    another scale as a rival."""
    specs = grid_specs(list(SOILS), [20.0, 80.0], [0.3, 0.65, 1.0], [0.15], 1, seed_base=0, duration_s=10.0)
    disc = _found_exactly(tmp_path, specs, "tests.sim_plugins:speed_weakening k=2 v0=0.3", ("gd2w_x", "fadevx0.3"),
                          2.0, pinned=False)
    assert any(r["name"].endswith("*fadevx0.3") for r in disc["pin"]["rivals"]), disc["pin"]
    assert disc["pin"]["few_levels"] is None  # three speeds: the factor's shape is judged by its rivals


def test_a_vertical_damping_is_found_as_one_signed_form(tmp_path):
    """A damping against the edge's vertical motion either way (tests/sim_plugins.vertical_damping,
    linear: F_z = 2 w d · 10 kPa · v_z / 5 cm/s on the soil), on 24 episodes at three depths: the
    search names one signed form on v_z, −w d · 10 kPa pushed up while rising, not its sinking half
    alone (which the library without the signed factor named, taking less off the held-out error,
    with hundreds of rivals). Not pinned down: the same column on γ d² w fits as well. (On the
    108-episode grid its k comes out lower, 1.55 for 2, most likely because Θ_k's v_z is the
    10-sample mean of paper §3.1, which lags the edge's sinking and rising.)"""
    specs = grid_specs(list(SOILS), [20.0, 80.0], [0.65], [0.1, 0.175, 0.25], 1, seed_base=0, duration_s=10.0)
    _found_exactly(tmp_path, specs, "tests.sim_plugins:vertical_damping k=40 v0=1", ("wd_z", "vz"), 2.0,
                   pinned=False, sign=-1.0)


def test_levels_of_a_held_variable_do_not_depend_on_where_a_window_begins(form_data):
    """How many levels of a speed the ticks sit at decides whether a factor of it can be pinned
    down. A two-speed grid whose dense soils slowed (0.27 m/s; 0.71-0.73 m/s for fewer ticks than a
    level needs; 0.86 or 0.87-0.89 m/s) is two levels: a window begun at the slowed episodes had
    reached across the gap into the upper speed, taken part of it and made a level of them (three
    speeds counted on a held-out part; with the upper speed from 0.87 m/s, an outside reviewer's).
    Slowed episodes enough for a level are one; three speeds are three, a middle speed held by a
    fifth of the ticks too; one speed with a few slowed episodes is one; a speed varying over a
    range is three or more."""
    from soil_discrepancy.forms import MIN_LEVEL_SHARE, held_levels
    from soil_discrepancy.frame import build_frame
    from soil_msgs_py.params import KNOWN_PARAMS

    frame = build_frame(form_data["saturating"], stride=STRIDE)
    rng = np.random.default_rng(0)

    def levels(*parts):
        """held_levels of the frame's ticks with v_x drawn from (share, low, high) uniform parts."""
        data = frame.select(episodes=list(frame.episodes))  # a copy of the frame's ticks
        n = len(data)
        counts = [int(round(share * n)) for share, _, _ in parts]
        counts[-1] = n - sum(counts[:-1])
        v = np.concatenate([rng.uniform(lo, hi, k) for k, (_, lo, hi) in zip(counts, parts)])
        data.known[:, KNOWN_PARAMS.index("v_x")] = rng.permutation(v)
        return held_levels(data, "v_x")

    few = 0.8 * MIN_LEVEL_SHARE
    for upper in (0.86, 0.87):
        slowed = levels((0.45, 0.24, 0.29), (few, 0.71, 0.73), (0.55 - few, upper, 0.89))
        assert len(slowed) == 2 and slowed[0] < 0.3 and slowed[1] > 0.85, (upper, slowed)
        assert len(levels((0.45, 0.24, 0.29), (0.11, 0.71, 0.73), (0.44, upper, 0.89))) == 3
    # slowed ticks nearer a level than half a window: a window begun at them had cut the level in two
    assert len(levels((0.45, 0.60, 0.62), (0.05, 0.70, 0.701), (0.5, 0.73, 0.79))) == 2
    assert len(levels((1 / 3, 0.29, 0.31), (1 / 3, 0.64, 0.66), (1 / 3, 0.99, 1.01))) == 3
    assert len(levels((0.4, 0.29, 0.31), (0.2, 0.64, 0.66), (0.4, 0.99, 1.01))) == 3
    assert len(levels((0.92, 0.64, 0.66), (0.08, 0.5, 0.52))) == 1
    assert len(levels((1.0, 0.05, 1.0))) >= 3  # a speed varying within the episodes


def test_a_catalogue_term_of_speed_is_not_pinned_down_on_two_speeds(form_data):
    """rate_strength claims a drag linear in v_x; on two speeds any factor of speed matches it (k and
    θ take the rest). A drag ∝ √v_x on a two-speed grid was named rate_strength, "pinned down", with
    v_x and v_x² listed as the same statement: the check on held levels read library forms only."""
    from soil_discrepancy.fee_fit import fit_fixed
    from soil_discrepancy.forms import pinned_caveat, rival_forms
    from soil_discrepancy.frame import build_frame

    frame = build_frame(form_data["saturating"], stride=STRIDE)
    for name in ("rate_strength", "soil_inertia"):
        assert force_terms.get_term(name).factor_variable == "v_x"
        model = AugmentedFEE([(name, 1.0)])
        pin = rival_forms(frame, model, fit_fixed(frame, model), name, alpha=0.01)
        assert pin["few_levels"] and pin["few_levels"]["variable"] == "v_x", pin
        assert len(pin["few_levels"]["levels"]) == 2 and not pin["pinned"], pin
        assert pin_kind(pin) != "pinned" and "v_x takes values in only 2 group(s)" in pinned_caveat(pin)


def test_a_form_in_the_place_of_another_effect_is_called_a_stand_in_not_its_mechanism(form_data):
    """A named form is the mechanism only if these data pin it down. On the entry drag's episodes
    (2 γ w d² exp(−s / 1 m)), a drag growing with time in soil takes part of it, but forms fading
    with travel take significantly more: that form is a stand-in, and the summary's words say so
    (a hard spot along the path and a layer that was not there were named so, each with a
    confident k); the right form's only rival is its own shape at another decay length."""
    from soil_discrepancy.fee_fit import fit_fixed
    from soil_discrepancy.forms import pinned_caveat, rival_forms
    from soil_discrepancy.frame import build_frame

    frame = build_frame(form_data["entry"], stride=STRIDE)
    # the grid's two speeds are two groups of v_x (its slowed dense episodes none of their own);
    # a cut ramping over the depths within one episode is several groups, not its one median
    from soil_discrepancy.forms import held_levels
    from soil_msgs_py.params import KNOWN_PARAMS
    assert [round(v, 1) for v in held_levels(frame, "v_x")] == [0.3, 1.0]
    ramp = frame.select(episodes=list(frame.episodes[:1]))
    ramp.known[:, KNOWN_PARAMS.index("d")] = np.linspace(0.05, 0.3, len(ramp))  # a copy of the frame's ticks
    assert len(held_levels(ramp, "d")) >= 3

    def pin(name, data=frame):
        model = AugmentedFEE([(name, 1.0)])
        return rival_forms(data, model, fit_fixed(data, model), name, alpha=0.01)

    wrong = pin("form:gd2w_x*tau")
    assert not wrong["pinned"] and wrong["n_better"] >= 1, wrong
    better = [r for r in wrong["rivals"] if r["better"]]
    assert better and term_forms.parse(better[0]["name"])[2].name.startswith("enter"), wrong["rivals"]
    assert better[0]["share"] > wrong["share"]
    words = pinned_caveat(wrong)
    assert "STAND-IN" in words and better[0]["name"] in words, words
    right = pin("form:gd2w_x*enter2")  # the hidden 1 m lies between the library's 0.5 m and 2 m
    assert right["n_better"] == 0 and (right["pinned"] or right["shape_pinned"]), right
    assert "STAND-IN" not in pinned_caveat(right) and right["share"] > 0.5
    # on 6 episodes a Wilcoxon over episodes with two against it stays above 0.01: not known, not "not pinned"
    few = pin("form:gd2w_x*enter2", frame.select(episodes=list(frame.episodes[:6])))
    assert few["pinned"] is None and few["n_episodes"] == 6 and "too few" in pinned_caveat(few), few
    with pytest.raises(ValueError, match="not a term of the model"):
        rival_forms(frame, AugmentedFEE(), fit_fixed(frame, AugmentedFEE()), "form:gd2w_x*enter2", alpha=0.01)


def test_the_fading_factor_is_the_decay_with_forward_speed():
    v = np.array([0.0, 0.3, 1.0, -0.2])
    s = ForceInputs(d=0 * v + 0.2, q=0 * v, v_x=v, v_z=0 * v, gamma=0 * v + 18e3, w=0 * v + 2.0, rho=0 * v + 1.4,
                    alpha=0 * v, phi=0 * v + 0.5, c=0 * v, delta=0 * v + 0.2, distance_in_soil=0 * v + 1.0,
                    f_fee_x=0 * v + 1e3, f_fee_z=0 * v)
    bx, bz = term_forms.basis("form:gd2w_x*fadevx0.3", s, np)
    # backing up (v_x < 0) counts as at rest, like the saturating forms' max(v_x, 0)
    assert np.allclose(bx, 18e3 * 0.2**2 * 2.0 * np.exp(-np.maximum(v, 0.0) / 0.3)) and not bz.any()
    assert "exp(−v_x / 0.3 m/s)" in term_forms.describe("form:gd2w_x*fadevx0.3")["formula"]
    # 1 at rest, so only in the soil: on a scale that is not 0 out of it (the FEE force given), nothing there
    fx, _ = term_forms.basis("form:fee*fadevx0.3", replace(s, d=np.array([0.2, -0.01, 0.2, 0.0])), np)
    assert np.allclose(fx, 1e3 * np.exp(-np.maximum(v, 0.0) / 0.3) * np.array([1, 0, 1, 0]))


def test_the_layer_factor_is_the_face_area_in_the_layer():
    d = np.array([0.05, 0.15, 0.2, 0.3])
    s = ForceInputs(d=d, q=0 * d, v_x=0 * d + 0.5, v_z=0 * d, gamma=0 * d + 18e3, w=0 * d + 2.0, rho=0 * d + 1.4,
                    alpha=0 * d, phi=0 * d + 0.5, c=0 * d, delta=0 * d + 0.2, distance_in_soil=0 * d + 1.0,
                    f_fee_x=0 * d + 1e3, f_fee_z=0 * d)
    bx, bz = term_forms.basis("form:wd_x*below0.15", s, np)
    assert np.allclose(bx, 2.0 * np.maximum(d - 0.15, 0.0) * term_forms.P_REF_PA) and not bz.any()
    assert "(d − 0.15 m)+ / d" in term_forms.describe("form:wd_x*below0.15")["formula"]


def test_a_z_formula_folds_the_scales_sign_into_k():
    """A z scale presses down ("−w d · P"): the formula a user reads says which way the term acts
    once, and still equals the basis (k > 0: the relief pushes up, +z on the soil)."""
    relief = term_forms.describe("form:-wd_z*below0.15")["formula"]
    press = term_forms.describe("form:wd_z*below0.15")["formula"]
    assert relief.startswith("F_z = k · w d") and "−k" not in relief and "· −" not in relief
    assert press.startswith("F_z = −k · w d")
    assert term_forms.describe("form:-wd_z*below0.15")["words"].startswith("c-free area scale w d P_ref, pushing up")
    assert "minus" in term_forms.describe("form:-gd2w_x*sink")["words"]  # an x relief keeps its "minus"
    d = np.array([0.1, 0.25])
    s = ForceInputs(d=d, q=0 * d, v_x=0 * d + 0.5, v_z=0 * d, gamma=0 * d + 18e3, w=0 * d + 2.0, rho=0 * d + 1.4,
                    alpha=0 * d, phi=0 * d + 0.5, c=0 * d, delta=0 * d + 0.2, distance_in_soil=0 * d + 1.0,
                    f_fee_x=0 * d + 1e3, f_fee_z=0 * d)
    _, bz = term_forms.basis("form:-wd_z*below0.15", s, np)
    assert np.allclose(bz, 2.0 * np.maximum(d - 0.15, 0.0) * term_forms.P_REF_PA)  # + k w (d − 0.15)+ P


def test_forms_that_take_little_off_the_heldout_error_while_structure_remains_are_called_stand_ins():
    """A hard spot at one place along the path was named as three forms (entry, time, rising speed)
    that took 13 % off the held-out error with the residual's structure left: the verdict must not
    read them as the effect's mechanism. Forms that take much off, a single form (found beside an
    effect no form explains), catalogue terms and a set after which no structure remains keep the
    plain wording."""
    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.verdict import STAND_IN_MAX_GAIN, verdict_of

    def score(name):
        return TermScore(name=name, k=2.3, k_se=0.14, k_folds=[2.3] * 5, gain=0.08, p=1e-6)

    reg0 = {"significant": True, "flagged_variables": ["distance"]}
    remains = {"significant": True, "flagged_variables": ["distance", "t"]}

    def summary(names, after_rmse, reg1=remains):
        verdict, text = verdict_of([score(n) for n in names], reg0, {"before": {"rmse": 4380.0}, "after": {"rmse": after_rmse}}, reg1)
        assert verdict == ("partly explained" if reg1["significant"] else "explained"), verdict  # structure left: part
        return text

    little = 4380.0 * (1 - STAND_IN_MAX_GAIN) + 100.0
    text = summary(["form:-wd_x*enter0.5", "form:-mom_x*tau"], little)
    assert "stand-ins" in text and "rather than its mechanism" in text and "explain part" not in text, text
    assert "stand-ins" not in summary(["form:-wd_x*enter0.5", "form:-mom_x*tau"], 4380.0 * 0.5), "they take half off"
    assert "stand-ins" not in summary(["form:-wd_x*enter0.5"], little), "one form found beside an effect no form explains"
    assert "stand-ins" not in summary(["soil_inertia", "compaction_hardening"], little), "catalogue terms are mechanisms"
    assert "stand-ins" not in summary(["form:-wd_x*enter0.5", "form:-mom_x*tau"], little,
                                      {"significant": False, "flagged_variables": []})


def test_a_catalogue_term_named_with_a_k_its_mechanism_cannot_have_is_called_a_stand_in():
    """Two effects hidden at once, the library's forms off: compaction and soil inertia were named,
    and beside them base friction with k 2.29, a friction coefficient no soil has. The verdict and the
    report say it is a stand-in; a plausible k says nothing."""
    from soil_discrepancy.candidates import TermScore
    from soil_discrepancy.verdict import verdict_of

    def text(k):
        named = [TermScore(name="soil_inertia", k=2.9, k_se=0.05, k_folds=[2.9] * 5, gain=0.67, p=1e-6),
                 TermScore(name="base_friction", k=k, k_se=0.23, k_folds=[k] * 5, gain=0.11, p=1e-6)]
        verdict, words = verdict_of(named, {"significant": True, "flagged_variables": ["v_x"]},
                                  {"before": {"rmse": 1597.0}, "after": {"rmse": 578.0}})
        assert verdict == "explained"
        return words

    words = text(2.29)
    assert "base_friction (k = 2.29" in words and "beyond what friction under the blade base can be" in words, words
    assert words.count("STAND-IN") == 1 and "not that mechanism" in words, words
    assert "STAND-IN" not in text(0.4) and "beyond" not in text(0.4)


def test_a_term_is_pinned_down_only_where_every_part_of_the_data_pins_it():
    """The rival check on the selection part favours the term that won its place there, the one on
    the held-out part has half the episodes: the workflow keeps the answer that claims least, a
    stand-in on either part stays a stand-in, and a part too small to judge is left out (not known
    only if no part can judge)."""
    from soil_discrepancy.forms import pin_kind, weaker_pin

    def pin(part, **kw):
        base = {"pinned": False, "stand_in": False, "n_better": 0, "shape_pinned": False, "factor_pinned": False,
                "scale_pinned": False, "part": part}
        return {**base, **kw}

    pinned_sel, pinned_test = pin("selection", pinned=True), pin("held-out test", pinned=True)
    assert weaker_pin(pinned_test, pinned_sel) is pinned_test  # both pin it: the first given
    rival = pin("held-out test", shape_pinned=True)
    assert weaker_pin(rival, pinned_sel) is rival and weaker_pin(pinned_sel, rival) is rival
    stand_in = pin("selection", stand_in=True, n_better=2)
    assert pin_kind(weaker_pin(pin("held-out test"), stand_in)) == "stand-in"
    too_small = pin("held-out test", pinned=None)
    assert weaker_pin(too_small, pinned_sel) is pinned_sel and weaker_pin(too_small) is too_small
    assert pin_kind(weaker_pin(pin("held-out test", n_better=1), pin("selection"))) == "beaten"
    assert weaker_pin(None, pinned_sel) is pinned_sel and weaker_pin(None) is None


@pytest.mark.parametrize("n", [3, 6, 8, 9, 12])
def test_too_few_episodes_is_where_two_against_keep_the_wilcoxon_above_alpha(n):
    """``wilcoxon_p_two_against`` is scipy's exact one-sided p for n episodes of which the two of
    least |difference| go the other way; the rival check's 'too few' starts where that reaches α
    (9 episodes at α = 0.01: 5 / 2^9 < 0.01 <= 5 / 2^8)."""
    from scipy.stats import wilcoxon

    from soil_discrepancy.forms import wilcoxon_p_two_against

    diff = np.arange(1.0, n + 1.0)
    diff[:2] *= -1.0
    exact = wilcoxon(diff, alternative="greater", method="exact").pvalue
    assert wilcoxon_p_two_against(n) == pytest.approx(exact)
    assert (wilcoxon_p_two_against(n) < 0.01) == (n >= 9)


def test_the_closest_catalogue_term_is_one_the_form_runs_with_before_one_it_runs_against():
    """A form at +0.92 with one term and −0.95 with another is the first's mechanism, not the
    second's opposite; without a term within CLOSE_COS the largest |cos| is named."""
    assert closest_index([0.2, CLOSE_COS + 0.02, -0.95]) == 1
    assert closest_index([0.2, 0.5, -0.95]) == 2
    assert closest_index([0.2, -0.5, 0.3]) == 1


def test_a_catalogue_naming_two_terms_alike_or_with_a_misspelt_key_is_refused_naming_it(tmp_path):
    """Two entries of one name were taken, and the report said "'a' (…): not named; 'a' (…): not
    named"; a number as a name was taken; a misspelt 'terms' was refused without naming the key
    (an outside tester's)."""
    cases = (("terms:\n- {term: soil_inertia, name: a}\n- {term: rate_strength, name: a}\n",
              r"terms\[0\] and terms\[1\] are both named 'a'"),
             ("terms:\n- {term: soil_inertia, name: 123}\n", r"terms\[0\]\.name=123 must be a non-empty text"),
             ("trems:\n- {term: soil_inertia}\n", r"non-empty list 'terms' \(it has \['trems'\]: a misspelt key\?\)"),
             ("terms:\n- {term: soil_inertia}\nnotes: x\n", r"unknown top-level key\(s\) \['notes'\]"))
    for i, (text, said) in enumerate(cases):
        path = tmp_path / f"c{i}.yaml"
        path.write_text(text)
        with pytest.raises(ValueError, match=said):
            load_catalogue(path)
    path = tmp_path / "fine.yaml"  # a name of one term and a term named by itself stay apart
    path.write_text("terms:\n- {term: soil_inertia, name: soil_inertia}\n- {term: rate_strength}\n")
    assert [r["name"] for r in load_catalogue(path)] == ["soil_inertia", "rate_strength"]


def test_a_catalogue_with_a_huge_k_or_binary_content_is_refused_naming_it(tmp_path, capsys):
    """YAML has no bound on integers: a 400-digit k overflowed math.isfinite (a traceback); a binary
    file gave the codec's words without the file. Both are exit 2 naming the entry or the file."""
    from soil_discrepancy.cli import main as cli_main

    huge = tmp_path / "huge.yaml"
    huge.write_text(f"terms:\n- term: soil_inertia\n  k: {10**400}\n")
    with pytest.raises(ValueError, match=r"terms\[0\]\.k=1000.*\.\.\. \(\d+ characters\) is not a finite number"):
        load_catalogue(huge)
    exponent = tmp_path / "exponent.yaml"  # PyYAML reads 1e0 as a string: it was refused as "not a finite number"
    exponent.write_text("terms:\n- term: soil_inertia\n  k: 2e0\n")
    assert load_catalogue(exponent)[0]["k"] == 2.0
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"\xff\xfe\x00\x80terms: []\n")
    for path, said in ((huge, "terms[0].k="), (binary, "is not UTF-8 text")):
        assert cli_main([str(tmp_path), "--out", str(tmp_path / "o"), "--catalogue", str(path)]) == 2
        err = capsys.readouterr().err
        assert str(path) in err and said in err and len(err) < 300, err


def test_a_selection_larger_than_the_search_takes_is_thinned_evenly(monkeypatch):
    """Past MAX_TICKS analysed ticks (a full-size run at stride 1 or 2) the search thins them
    evenly before the regression; a frame of a few hundred ticks stands in for 20 000 here."""
    from pinn_estimator.dataset import Dataset
    from soil_discrepancy import forms
    from soil_discrepancy.fee_fit import fit_fixed
    from soil_discrepancy.frame import build_frame
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    specs = [EpisodeSpec(soil, 50.0, v, d, seed=k, duration_s=3.0)
             for k, (soil, (v, d)) in enumerate((s, c) for s in SOILS for c in ((0.3, 0.1), (1.0, 0.2)))]
    frame = build_frame(Dataset.from_episodes(list(run_episodes(SimConfig(world_mode="fee"), specs))), stride=2)
    monkeypatch.setattr(forms, "MAX_TICKS", len(frame) // 3)
    model = AugmentedFEE()
    out = forms.search_forms(frame, model, fit_fixed(frame, model), folds=2)
    assert out["library_size"] == len(term_forms.form_names()) and out["candidates"]


def test_a_users_catalogue_refuses_a_misspelt_field_and_a_term_given_twice(tmp_path):
    """'kk: 0.3' was dropped in silence (k then free), and one term under two names was tested
    once and said under one of them."""
    good = tmp_path / "good.yaml"
    good.write_text("terms:\n- term: soil_inertia\n  name: my inertia\n  k: 0.5\n  formula: anything, not read\n")
    assert load_catalogue(good) == [{"term": "soil_inertia", "name": "my inertia", "k": 0.5}]
    typo = tmp_path / "typo.yaml"
    typo.write_text("terms:\n- term: soil_inertia\n  kk: 0.3\n")
    with pytest.raises(ValueError, match=r"terms\[0\]: unknown field\(s\) \['kk'\]; known: \['term', 'name', 'k'"):
        load_catalogue(typo)
    twice = tmp_path / "twice.yaml"
    twice.write_text("terms:\n- term: soil_inertia\n  name: a\n- term: soil_inertia\n  name: b\n")
    with pytest.raises(ValueError, match=r"terms\[0\] and terms\[1\] are the same term 'soil_inertia'"):
        load_catalogue(twice)


def test_a_form_not_significantly_better_than_the_catalogues_term_gives_way_to_it(tmp_path):
    """Rate strengthening with a negative k (a strength lost with speed, linear: −3 kPa·s/m), a
    catalogue term when negative k is allowed: a decay form, exp(−v_x / 0.3 m/s), took 65 % off the
    cross-validated error where rate_strength took 66 %, and the form had been named, a wrong name.
    Within the noise (the forms' per-episode errors not significantly below the catalogue's) the
    mechanism is named, with its k, and the report says why."""
    specs = grid_specs(["Clay", "Loam"], [20.0, 80.0], [0.3, 1.0], [0.1, 0.25], 1, seed_base=0, duration_s=10.0)
    neg = simulated(specs, ("soil_physics.force_terms:plugin term=rate_strength k=-3000",))
    rep = run_discrepancy(dataset=neg, out_dir=tmp_path / "out", plots=False, allow_negative_k=True,
                          **{**RUN, "stride": 10})
    accepted = rep["selection"]["accepted"]
    assert accepted and accepted[0]["name"] == "rate_strength" and -3600 < accepted[0]["k"] < -2400, rep["summary"]
    path = rep["forms"]["catalogue_path"]
    assert path["chosen"] == "catalogue", path
    if path["catalogue_left"] > path["forms_left"]:  # taken for the noise, and said so
        assert path["p_forms_better"] >= 0.01 and "not significantly below" in (tmp_path / "out" / "discrepancy.md").read_text()


def test_the_report_says_a_rival_is_not_shown_worse_rather_than_worse():
    """A rival is listed because the test that it fits worse than the named form did not pass; it
    read "worse at p 0.212", which an outside reader took for a claim that it is worse (while it
    took more of the residual)."""
    from soil_discrepancy.report import _pinned_md

    rival = {"name": "form:gd2w_x*enter0.5", "k": 0.5, "share": 0.152, "p_worse": 0.212, "better": False}
    pin = {"pinned": False, "stand_in": False, "n_better": 0, "shape_pinned": False, "factor_pinned": False,
           "scale_pinned": False, "share": 0.109, "n_episodes": 22, "n_rivals": 1, "rivals": [rival]}
    text = "\n".join(_pinned_md(pin))
    assert "fit it not significantly worse" in text and "takes 15.2 % (the test that it fits worse: p 0.212)" in text
    assert "worse at p" not in text
    pinned = {**pin, "pinned": True, "runner_up": {**rival, "p_worse": 0.001}, "rivals": []}
    assert "(the best, `form:gd2w_x*enter0.5`, 15.2 %, worse: p 0.001)" in "\n".join(_pinned_md(pinned))


def test_without_soil_labels_an_unpinned_verdict_says_what_it_could_not_check(form_data, form_reports, tmp_path):
    """Labelled, a soil fitted beside a form not pinned down is checked against its label's textbook
    range, and one outside makes the verdict "partly explained"; without labels nothing is, and an
    outside tester's drags read "explained" there without a word of what was not checked."""
    import dataclasses

    blind_labels = dataclasses.replace(form_data["saturating"], metas=[
        dataclasses.replace(m, soil="unknown", relative_density_pct=float("nan")) for m in form_data["saturating"].metas])
    rep = run_discrepancy(dataset=blind_labels, out_dir=tmp_path, plots=False, **{**RUN, "stride": STRIDE})
    assert rep["settings"]["group_by"] == "gamma" and rep["verdict"] == "explained", rep["summary"]
    said = "no group has a catalogue soil's label, so the soil fitted beside them is checked against no textbook range"
    assert said in rep["summary"] and said not in form_reports["saturating"]["summary"]


def test_a_chatter_one_tick_in_two_would_fold_into_a_slow_signal_is_analysed_at_every_tick(tmp_path):
    """A 29.9 Hz chatter of a fifth of |F|: every 2nd tick (30 Hz) folds it to 0.1 Hz, which an outside
    reader's run named as a relief growing with time in soil, "pinned down". The force varies more
    within each 2 ticks than from one analysed tick to the next, so every tick is analysed: no term
    named, and the report says why. White noise of that size folds nothing."""
    from soil_discrepancy.frame import build_frame, folded_vibration

    shaken = simulated(small_grid(), ("tests.sim_plugins:chatter k=0.5 f_hz=29.9",))
    assert folded_vibration(build_frame(shaken, stride=2), 0.02) == ["x"]
    rep = run_discrepancy(dataset=shaken, out_dir=tmp_path, plots=False, **{**RUN, "stride": 2})
    assert rep["settings"]["stride"] == 1 and rep["settings"]["stride_asked"] == 2, rep["settings"]
    # (on these 32 episodes "no significant discrepancy" beside the note; on the reader's 108 "unexplained",
    # the residual "alternating from tick to tick")
    assert rep["selection"]["accepted"] == [] and rep["verdict"] in ("unexplained", "no significant discrepancy")
    assert "analysed every tick, not one in 2: within each 2 ticks the force varies beyond noise by RMS x " \
           in rep["summary"], rep["summary"]
    # a frame given ready-made is analysed as built, and the verdict says to build it at every tick
    given = run_discrepancy(frame=build_frame(shaken, stride=2), plots=False, **RUN)
    assert given["settings"]["stride"] == given["settings"]["stride_asked"] == 2
    assert "the frame given analyses one tick in 2, which may fold a vibration" in given["summary"], given["summary"]
    quiet = simulated(small_grid())
    noisy = replace(quiet, forces=quiet.forces + np.random.default_rng(3).normal(size=quiet.forces.shape) * 2000.0)
    for stride in (2, 8):
        assert folded_vibration(build_frame(noisy, stride=stride), 0.02) == []
        assert folded_vibration(build_frame(quiet, stride=stride), 0.02) == []
    # in the default world its noise and particle events change the force between analysed ticks as much
    # as the chatter within them (an outside reviewer's: a plain ratio of the two missed it there)
    assert folded_vibration(build_frame(simulated(small_grid(), ("tests.sim_plugins:chatter k=0.5 f_hz=29.9",),
                                                  mode="default"), stride=2), 0.02) == ["x"]
    assert folded_vibration(build_frame(simulated(small_grid(), mode="default"), stride=2), 0.02) == []
