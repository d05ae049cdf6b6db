"""The discrepancy report's verdict and its words: what ``run_discrepancy``'s figures let it say, and how strongly.

The verdict is one of ``VERDICTS``; its summary names the terms with their k and the held-out
gap, and says where an answer is weaker than it looks: a form the data do not pin down, a
possible stand-in (``STAND_IN_MAX_GAIN``), a soil moved beside a form (``theta_shift``), θ on a
soil test's bound, structure left in the residual, a soil the model cannot follow. Nothing is
fitted or tested here: the words are read off the workflow's results (the move of θ is their
difference), so each claim can be traced to a figure of the report.
"""
from __future__ import annotations

import math

import numpy as np

from soil_msgs_py.soil_labels import GAMMA_GROUP_PREFIX
from soil_physics import force_terms, term_forms
from soil_physics.term_forms import PREFIX as FORM_PREFIX

from .forms import pin_kind, pinned_caveat
from .gap import NO_WORSE_WITHOUT, confirmation
from .regimes import (ONE_DEPTH_SPAN_M, flagged_rows, misfit_discrepancy, misfit_unit_name, on_soil_test_bound,
                      variable_labels)
from .soil_tests import OUTSIDE_BY_CHANCE, WIDTH_SIGMA

# "partly explained": terms are named and the residual keeps significant structure beside them (a
# verdict of "explained" there read as more than the summary's "the named terms explain part")
VERDICTS = ("explained", "partly explained", "unexplained", "no significant discrepancy")
# Several discovered forms that together take less than this share off the held-out force error
# while the residual keeps its structure may be stand-ins, and the verdict says so: a patchwork
# that follows part of an effect whose own form the library does not hold. A hard spot at one
# place along the path was named as three forms on entry, time and rising speed (−13 %, 4.0 kN of
# slow residual left of 4.1 kN), each with a confident k; the effects found in their own form took
# 31-76 % off. One form is left its name: beside a second effect no form explains, the one that
# is found takes little off the whole (a suction found exactly beside a deep drag: −6 %).
STAND_IN_MAX_GAIN = 0.25

# How far the named terms may move a group's soil before the report says so: about what a soil
# test's interval allows (± 2 standard deviations of a shear test's φ and c, soil_tests.py's examples)
THETA_SHIFT_NOTE = {"phi_deg": 3.0, "c_pa": 1e3, "delta_deg": 3.0}
# How the verdict and the report show a move of θ: key -> (symbol, unit, per unit of the θ table, decimals)
THETA_SHIFT_DISPLAY = {"phi_deg": ("φ", "°", 1.0, 1), "c_pa": ("c", " kPa", 1e-3, 2), "delta_deg": ("δ", "°", 1.0, 1)}


def theta_move_text(key: str, value: float, signed: bool = True) -> str:
    """A move (or its size) of θ's ``key`` in its display unit: '+27.0°', '-5.28 kPa', '1.63 kPa'."""
    _, unit, scale, decimals = THETA_SHIFT_DISPLAY[key]
    return f"{value * scale:{'+' if signed else ''}.{decimals}f}{unit}"


def theta_shift(before: list[dict], after: list[dict] | None) -> dict | None:
    """Per soil parameter, the largest move of a group's fitted θ once the named terms are in the
    model (``after``) against the baseline's (``before``), with the group; None without named terms.

    Why: a term and θ can trade off (a relief fading with speed wants a stronger soil, a rate law's
    offset becomes a cohesion in sand): the force then fits, but the soil estimates, which a planner
    forecasts from, are another soil's; nothing else in the report shows it."""
    if after is None:
        return None
    old = {r["group"]: r for r in before}
    out = {}
    for key in THETA_SHIFT_NOTE:
        moves = [(r[key] - old[r["group"]][key], r["group"]) for r in after if r["group"] in old]
        if moves:
            delta, group = max(moves, key=lambda m: abs(m[0]))
            out[key] = {"largest": float(delta), "group": group,
                        "mean_abs": float(np.mean([abs(m[0]) for m in moves])), "note_above": THETA_SHIFT_NOTE[key]}
    return out


def _bound_hits(reg: dict | None) -> dict[str, list[str]]:
    """θ-group -> where its fitted soil sits on its fit box (``regimes.group_misfit``'s rows; {} without)."""
    return {r["name"]: r["theta_at_bound"] for r in _group_rows(reg)}


def _on_fit_box(reg: dict | None) -> list[str]:
    """The θ-groups cut at more than one depth whose fitted soil sits on its fit box, the physical
    range (not on a soil test's bound, not a group of one depth, where θ slides along the φ-c ridge
    to its box with nothing missing)."""
    return [r["name"] for r in _group_rows(reg) if not r.get("one_depth")
            and any(not on_soil_test_bound(b) for b in r["theta_at_bound"])]


def _at_bound(reg: dict | None) -> set[str]:
    """The θ-groups whose fitted soil sits on its fit box, but for groups cut at one depth, where θ
    slides along the φ-c ridge to its box with nothing missing (``regimes.ONE_DEPTH_SPAN_M``)."""
    return {r["name"] for r in _group_rows(reg) if r["theta_at_bound"] and not r.get("one_depth")}


def theta_shift_text(shift: dict | None, reg0: dict | None = None, reg1: dict | None = None) -> str:
    """The verdict's words (beside a named form that is not pinned down) where the named terms move a
    group's θ more than ``THETA_SHIFT_NOTE`` (``reg0`` / ``reg1``: the baseline's and the augmented
    model's regimes with their misfit rows). Where the terms release θ from the fit box broadly (at
    most half as many groups on it with them), a group whose θ leaves the box the baseline's sat on
    is the sign of an effect the baseline's θ took in (soil inertia: dense loam's φ 5° on the box,
    32° with the term, for 33.6°; a tip penetration hidden on another grid: 12 groups on the box → 0,
    clay's φ back to 16.9° for 18°), so it is said as speaking for the terms; any other move, a group
    reaching the box among them (a term that takes part of the soil), as a trade-off that makes the
    soil the form's as much as the data's (tagged where θ left the box: in the default world 11 groups
    sat on it, 9 with two forms). Neither proves it: a soil test does."""
    before, after = _at_bound(reg0), _at_bound(reg1)
    released = bool(before) and 2 * len(after) <= len(before)
    moved_groups = {v["group"] for v in (shift or {}).values()}
    freed, traded = [], []
    for k, v in (shift or {}).items():
        if abs(v["largest"]) <= v["note_above"]:
            continue
        group = v["group"]
        move = f"{THETA_SHIFT_DISPLAY[k][0]} {theta_move_text(k, v['largest'])} in {group}"
        if group in before and group not in after:
            (freed if released else traded).append(move + ("" if released else ", off its fit box with them"))
        else:
            traded.append(move + (", onto its fit box with them" if group in after and group not in before else ""))
    text = ""
    if traded:
        # both kinds at once are of different groups: each sentence says which (a reader took the two for one)
        text += (f"; {'in some groups ' if freed else ''}the soil fitted beside them is another ({'; '.join(traded)}; the table \"θ per group\"): a form "
                 "that is not pinned down and θ trade off, so that soil is the form's as much as the data's"
                 + _soil_test_hint([r for r in _group_rows(reg1) if r["name"] in moved_groups],
                                   "; a soil test tells (--soil-tests)"))
    if freed:
        text += (f"; {'in other groups ' if traded else ''}the soil fitted beside them leaves the fit box the baseline's sat on ({'; '.join(freed)}; the "
                 "table \"θ per group\"): they take what the baseline's θ had taken in, which speaks for them taking the "
                 "effect's force, not for their form being its mechanism")
    return text


GEOMETRIC_SCALE_VARIABLES = frozenset({"d", "v_x"})  # shape_caveat: the variables of a scale that is a law of the cut


def shape_caveat(name: str, pin: dict | None, reg1: dict | None, labels: dict) -> str:
    """The words a pinned-down form carries when structure remains, once it is in the model, in a
    variable its factor is a function of (``term_forms.factor_variable``) or its scale varies with
    (``term_forms.SCALE_VARIABLES``; a scale that is a law of the cut's geometry, of d and v_x only:
    the model's own force and the pile vary with every motion variable, and structure another
    effect leaves there says nothing of their law): the library's best law there, not the effect's. (A drag
    growing linearly with travel up to a cap, named as 1 − exp(−s / 2 m) with k 1.8 for 1.5, left
    structure vs distance; a load cell drifting with time, the same at every depth, named as
    w d · τ, "pinned down" since the library has no depth-free scale growing with time, left
    structure vs the cut depth; every form the library holds exactly, found on the hidden-effect
    grid, left none. A form whose factor alone is pinned down says so of its factor: a z force acting
    only above 0.8 m/s, named with the factor (v_x / 1 m/s)², "its factor is pinned down", left
    structure vs v_x.) A factor of travel on a scale of the cut's depth (or none) is judged by v_x too,
    through which travel is seen."""
    kind = pin_kind(pin)
    if not name.startswith(FORM_PREFIX) or kind not in ("pinned", "scale", "value") or not reg1 \
            or not reg1.get("significant"):
        return ""
    _, scale, factor = term_forms.parse(name)
    flagged = reg1.get("flagged_variables") or []
    var = term_forms.factor_variable(factor.name)
    pinned = "pinned down" if kind == "pinned" else "its factor is pinned down"
    if var is not None and var in flagged:
        return (f"; {pinned} among the library's forms, but structure remains vs {labels.get(var, var)} with it: "
                "the effect's shape there is near the form's, not the form's, and its k is the nearest shape's")
    law = term_forms.SCALE_VARIABLES.get(scale.name, ())
    if factor.name in term_forms.DISTANCE_FACTORS and "v_x" in flagged and set(law) <= {"d"}:
        # travel is seen through the speed: an analysed stretch of t s holds s = v_x t, so a wrong
        # shape in s leaves a residual that varies with v_x from one episode to the next (an outside
        # tester's 2 kN drag over the first metre, the same at every depth, named w d · exp(−s / 0.5 m),
        # "pinned down", left structure vs v_x alone). Not on a scale that varies with v_x itself (the
        # branch below says so of it) or with every motion (the model's force, the pile), where
        # structure vs v_x may be another effect's.
        return (f"; {pinned} among the library's forms, but structure remains vs {labels.get('v_x', 'v_x')} with "
                f"it, through which travel is seen (s = v_x t): the effect's shape in travel, or its scale, is near "
                "the form's, not the form's, and its k is the nearest form's")
    if kind != "pinned":
        return ""
    scale_vars = [v for v in law if v in flagged] if set(law) <= GEOMETRIC_SCALE_VARIABLES else []
    if scale_vars:
        said = " and ".join(labels.get(v, v) for v in scale_vars)
        return (f"; pinned down among the library's forms, but structure remains vs {said}, which its scale "
                f"{scale.formula} varies with: the effect may not scale so, and its k is the nearest law's")
    return ""


def travel_caveat(name: str, reg0: dict | None) -> str:
    """The words a discovered form of travel s or of time in soil τ carries where the episodes were cut
    at one speed each (``regimes.travel_is_speed_times_time``): s = v_x τ there, so the form's law of
    one is as much a law of the other at the episode's speed (an outside reader's drag ∝ v_x τ was
    named w d · s, "pinned down", and the report called compaction's travel "the same mechanism")."""
    if not name.startswith(FORM_PREFIX) or not (reg0 or {}).get("travel_is_speed_times_time"):
        return ""
    if not (term_forms.uses_distance(name) or term_forms.uses_time(name)):
        return ""
    return ("; each episode was cut at one speed, so travel is speed × time in soil here (s = v_x τ): a law of "
            f"{'time at that speed' if term_forms.uses_distance(name) else 'travel'} fits as well, and only a cut "
            "whose speed changes tells them apart")


def position_caveat(name: str, reg0: dict | None) -> str:
    """The words a named term of travel in soil (a catalogue term or a form) carries where every episode
    entered the soil at one place along the path (``regimes.travel_is_position``): travel is position
    there, so a soil that changes along the path fits as well (an outside tester's soil strengthening
    from 3 m on was named compaction by travel, "explained", "pinned down")."""
    x = (reg0 or {}).get("travel_is_position_m")
    if x is None or not force_terms.uses_distance(name):
        return ""
    return (f"; every episode entered the soil at one place along the path (x ≈ {x:.1f} m), so travel in soil is "
            "position along the path here: a soil that changes along the path fits as well, and only cuts that enter "
            "the soil at different places tell them apart")


def clock_caveat(name: str, reg0: dict | None) -> str:
    """The words a named term of time in soil carries where every recording began at one moment before
    its cut (``regimes.time_in_soil_is_clock``): time in soil is the recording's clock less a constant
    there, so a drift with the clock (a sensor's gain, a machine warming up) fits as well."""
    t0 = (reg0 or {}).get("time_in_soil_is_clock_s")
    if t0 is None or not force_terms.uses_time(name):
        return ""
    return (f"; every recording's cut began at one moment of it (t ≈ {t0:.1f} s), so time in soil is the recording's "
            "clock less a constant here: a drift with the clock (a sensor's gain, a machine warming up) fits as well, "
            "and only recordings that start at different moments before the cut tell them apart")


def _acts_on(name: str, axis: str) -> bool:
    """Whether term ``name`` has a part on ``axis`` ('x' or 'z', ``force_terms.Term.axes``): a term of
    one axis has none on the other (an outside reader's x-only forms were said to have a z part "not
    in the data")."""
    return axis in force_terms.get_term(name).axes


def fmt_n(x) -> str:
    """A force [N] for a message; '–' where a model was undefined on every tick (None)."""
    return "–" if x is None else f"{x:.0f}"


def _pct_change(before: float, after: float) -> str:
    """The force at another depth before -> after, as every verdict and log line says it."""
    return f"{before:.1f} -> {after:.1f} % of |F|"


def forecast_gap_text(test: dict) -> str:
    fc = test.get("depth_forecast") or {}
    if not fc.get("before"):
        return "not measured (no two depths in a held-out group)"
    return _pct_change(fc['before']['vector_pct'], fc['after']['vector_pct'])


def unconfirmed_reason(figures: dict) -> str:
    """Why held-out figures (``workflow._confirmation``'s, with their rule's ``min_gain`` and ``alpha``)
    did not confirm named terms, in words (``gap.confirmation``); "" where they did (a set the
    held-out episodes confirmed, one of whose terms failed term by term) or the rule is not given."""
    if figures.get("min_gain") is None or figures.get("alpha") is None:
        return ""
    ok, why = confirmation(figures.get("sse_reduction"), figures.get("forecast_reduction"), figures.get("forecast_p"),
                           figures["min_gain"], figures["alpha"])
    return "" if ok else why


def _forecast_clause(figures: dict) -> str:
    """", force at another depth B -> A % of |F|" from ``_confirmation``'s figures ("" where not measured)."""
    before, after = figures.get("forecast_pct_before"), figures.get("forecast_pct_after")
    return "" if before is None or after is None else f", force at another depth {_pct_change(before, after)}"


def verdict_of(new_terms, reg0: dict, test: dict | None, reg1: dict | None = None,
               forms: dict | None = None, tentative: dict | None = None, pins: dict | None = None,
               shift: dict | None = None, user_names: dict | None = None) -> tuple[str, str]:
    """(verdict, summary). Only confirmed terms are named (``new_terms``); ``tentative``: the
    terms the held-out test did not confirm, mentioned as such; ``pins``: {name: ``rival_forms``},
    whose caveat a term its data do not pin down carries; ``user_names``: {term: the name a user's
    catalogue gave it}, which the summary says first."""
    labels = variable_labels()
    not_named = ""
    idle = [t["name"] for t in (tentative or {}).get("terms", []) if t.get("why") == "idle"]
    if tentative and len(idle) == len(tentative["terms"]):
        not_named = (f" (tentative, NOT confirmed term by term on the held-out test episodes: "
                     f"{', '.join(idle)} passed cross-validation on the selection part, but removing it leaves "
                     f"{NO_WORSE_WITHOUT})")
    elif tentative:
        not_named = (f" (tentative, NOT confirmed on the held-out test episodes: "
                     f"{', '.join(t['name'] for t in tentative['terms'] if t.get('why') != 'idle')} passed cross-validation on the selection part, "
                     f"held-out RMSE with all named terms {fmt_n(tentative['test_rmse_before'])} -> "
                     f"{fmt_n(tentative['test_rmse_after'])} N"
                     + _forecast_clause(tentative) + unconfirmed_reason(tentative)
                     + (f"; term by term, removing {', '.join(idle)} leaves {NO_WORSE_WITHOUT}" if idle else "")
                     + ")")
    if new_terms:
        parts, stand_ins = [], []  # stand_ins: terms fitted with a k their mechanism cannot have
        for s in new_terms:
            unit = force_terms.get_term(s.name).k_unit
            se = f" ± {s.k_se:.2g}" if math.isfinite(s.k_se) else ""
            unit = "" if unit == "1" else f" {unit}"
            label = s.name
            pin = (pins or {}).get(s.name)
            caveat = (pinned_caveat(pin) + shape_caveat(s.name, pin, reg1, labels) + travel_caveat(s.name, reg0)
                      + position_caveat(s.name, reg0) + clock_caveat(s.name, reg0))
            if implausible := force_terms.implausible_k(s.name, s.k):
                caveat += f"; {implausible}: a STAND-IN taking another effect's force, not that mechanism"
                stand_ins.append(s.name)
            given = (user_names or {}).get(s.name)
            if given and given != s.name:  # the user's name first (the summary had said only the formula)
                label = (f"'{given}', the form {force_terms.get_term(s.name).formula} ({s.name})"
                         if s.name.startswith(FORM_PREFIX) else f"'{given}' ({s.name})")
            elif s.name.startswith(FORM_PREFIX):
                label = f"discovered form {force_terms.get_term(s.name).formula} ({s.name})"
            parts.append(f"{label} (k = {s.k:.4g}{se}{unit}, removes {100 * s.gain:.0f} % of the cross-validated "
                         f"error{caveat})")
        text = "missing effect: " + "; ".join(parts)
        gain = None  # the share of the held-out test's force RMSE the named terms take off
        worse_axes = []
        if test is not None and test["before"]["rmse"] is not None and test["after"]["rmse"] is not None:
            b, a = test["before"]["rmse"], test["after"]["rmse"]
            gain = 1.0 - a / b if b > 0 else None
            text += f"; held-out test RMSE {b:.0f} N -> {a:.0f} N ({100 * (a / b - 1):+.0f} %)"
            if (test.get("depth_forecast") or {}).get("before"):
                text += f", force at another depth {forecast_gap_text(test)}"
            worse_axes = _worse_axes(test)
            for axis, (rb, ra, mb, ma) in worse_axes:
                text += (f"; but the held-out {axis} error rises (RMSE {rb:.0f} -> {ra:.0f} N, mean |error| {mb:.0f} -> "
                         f"{ma:.0f} N): " + (f"the named terms' {axis} part is not in the data (an effect on the other "
                                              "axis only, or another form on this one)"
                                              if any(_acts_on(s.name, axis) for s in new_terms) else
                                              f"the named terms have no {axis} part, so the soil refitted beside them "
                                              f"moved {axis}: they take in more than the effect on the other axis"))
        # structure beside the named terms, in a regime or in some soils' fit: "partly explained"
        remains = reg1 is not None and (reg1["significant"] or bool(misfit_discrepancy(reg1)))
        weak = weak_forms_only(new_terms, pins, gain)
        if weak and not remains:  # nothing significant left, but what was named is a weak, unpinned fit
            text += (f"; partly, at best: the named form{'s' if len(new_terms) > 1 else ''} take{'' if len(new_terms) > 1 else 's'} "
                     f"only {100 * gain:.0f} % off the held-out error and {'are' if len(new_terms) > 1 else 'is'} not "
                     "pinned down: a stand-in that follows part of an effect whose own form the library may not hold "
                     "(a drift of the sensor, a law of another variable); the residual left says what is missing")
        if remains:
            text += ("; structure remains vs " + ", ".join(labels.get(v, v) for v in reg1["flagged_variables"])
                     if reg1["significant"] else "; structure remains in some soils' fit, in no regime")
            forms_named = sum(s.name.startswith(FORM_PREFIX) for s in new_terms)
            if gain is not None and gain < STAND_IN_MAX_GAIN and forms_named >= 2:
                text += (f" (the named terms take only {100 * gain:.0f} % off the held-out error with {forms_named} "
                         "discovered forms: they may be stand-ins that follow part of an effect whose own form the library "
                         "does not hold, rather than its mechanism; look where the structure is)")
            else:
                text += " (the named terms explain part of the discrepancy)"
        # with soil tests, a term that is the effect's mechanism releases θ from the tests' bounds to what
        # chance leaves there (an adhesion named as −k c w d: 6 groups on a bound → 0); one that leaves
        # more there than chance would takes force θ could not, not what pushed θ there (a drag with
        # density named by two forms: 8 → 10; a drag ∝ √d named as a constant force, "pinned down":
        # 12 → 6; a drag ∝ d^1.5 named as one ∝ d²: 12 → 11). As many as before but within chance (one
        # group of twelve, before and after) is no sign: the same tests bound both fits.
        held0, held1 = _on_test_bounds(reg0), _on_test_bounds(reg1)
        chance = bound_hits_by_chance(reg1)
        bound_stand_ins = bool(held1) and chance < reg1["misfit"]["alpha"]
        if bound_stand_ins:
            text += (f"; with the soil tests θ stays on a test's bound in {held1} groups ({held0} without the named "
                     f"terms; by chance as many or more {_rarely(chance)}): they do not take what "
                     "pushes θ there, and may be STAND-INS for an effect whose own form the library does not hold")
        # a form not pinned down and θ can trade off: the soil fitted beside it is the form's as much as
        # the data's (beside a pinned-down term the move is what the baseline's θ had taken in)
        hedged = bool(stand_ins) or any(pin_kind((pins or {}).get(s.name)) not in (None, "pinned") for s in new_terms)
        moved = theta_shift_text(shift, reg0, reg1) if hedged else ""
        # a soil beside them its label's textbook rules out: "explained" at most in part, pinned down or not
        off_label = _off_label_text(reg1, beside_terms=True)
        verdict = "partly explained" if remains or weak or bound_stand_ins or worse_axes or off_label else "explained"
        # without a catalogue soil's label the soil fitted beside a form not pinned down is checked against
        # no textbook range: the same bags labelled read "partly explained" where it falls outside (an outside
        # tester's d^1.5 and √v_x drags: "explained" unlabelled, "partly explained" labelled)
        rows = _group_rows(reg1)
        if verdict == "explained" and hedged and rows and not any(r.get("range_checked", True) for r in rows):
            moved += ("; no group has a catalogue soil's label, so the soil fitted beside them is checked against no "
                      "textbook range (with one, a soil fitted outside it makes the verdict \"partly explained\")")
        return (verdict, text + _untested_text(test) + moved + off_label + misfit_text(reg1) + _left_text(reg1) + not_named)
    if reg0["significant"] or misfit_discrepancy(reg0):
        names = ", ".join(labels.get(v, v) for v in reg0["flagged_variables"])
        where = (f"residual structure vs {names}" if reg0["significant"] else
                 f"no regime bias, but some soils fit worse than the others, by at least {100 * reg0['min_effect']:.0f} % "
                 "of |F|")
        what = "neither a catalogue term nor a form of the library explains" if forms else "no catalogue term explains"
        text = f"unexplained: the model and the data disagree systematically ({where}), but {what} it on held-out episodes"
        forms_tentative = (forms or {}).get("not_confirmed")
        if forms_tentative and forms_tentative["forms"]:
            text += (f" (tentative forms {', '.join(forms_tentative['forms'])} passed cross-validation on the selection part "
                     f"but not the held-out test: RMSE {fmt_n(forms_tentative['test_rmse_before'])} -> "
                     f"{fmt_n(forms_tentative['test_rmse_after'])} N{_forecast_clause(forms_tentative)}"
                     f"{unconfirmed_reason(forms_tentative)})")
        return "unexplained", (text + _untested_text(test) + misfit_text(reg0) + _off_label_text(reg0) + _left_text(reg0)
                               + not_named)
    quiet = (f"no regime bias or trend of at least {100 * reg0['min_effect']:.0f} % of |F| at p < {reg0['alpha']:g} "
             "(Holm), and no catalogue term reduces the held-out error")
    if off_box := _on_fit_box(reg0):
        # θ on the physical box where the cuts of several depths pin it: the FEE fits these forces only with a
        # soil no soil is, an effect θ took in (an outside reader's φ falling 3° per 0.1 m of depth, 17 % of
        # |F|, had been "no significant discrepancy" beside φ on its box in 4 of 12 groups)
        return "unexplained", (f"unexplained: {quiet}, but the model fits these forces only with a soil outside the "
                               f"physical range in {len(off_box)} group(s) cut at more than one depth: an effect θ takes "
                               "in, which no regime shows" + misfit_text(reg0) + _off_label_text(reg0) + not_named)
    return "no significant discrepancy", (f"no significant discrepancy: {quiet}" + misfit_text(reg0, quiet=True)
                                          + _off_label_text(reg0) + not_named)


# pin_kind: the form itself is not pinned down ("levels": its factor cannot be, over too few depths or speeds)
WEAK_PIN_KINDS = ("stand-in", "beaten", "form", "levels")


def unpinned_forms_only(named: dict[str, dict | None]) -> bool:
    """Whether every named term (name -> its ``rival_forms`` result) is a discovered form its data
    do not pin down (``WEAK_PIN_KINDS``): the residual is taken, but which form takes it the data
    do not say. A catalogue term is a mechanism, never counted here."""
    return bool(named) and all(name.startswith(FORM_PREFIX) and pin_kind(pin) in WEAK_PIN_KINDS
                               for name, pin in named.items())


def weak_forms_only(new_terms, pins: dict | None, gain: float | None) -> bool:
    """Whether every named term is a discovered form its data do not pin down
    (``unpinned_forms_only``) and together they take less than STAND_IN_MAX_GAIN off the held-out
    error: then the verdict is "partly explained" even with no significant structure left (a
    sensor drift named as a form scaled by the cut's area took 24 % off and was called explained)."""
    return (bool(new_terms) and gain is not None and gain < STAND_IN_MAX_GAIN
            and unpinned_forms_only({s.name: (pins or {}).get(s.name) for s in new_terms}))


def _on_test_bounds(reg: dict | None) -> int:
    """How many θ-groups sit on a soil test's bound (``regimes.group_misfit``'s rows; 0 without soil tests)."""
    return sum(1 for hits in _bound_hits(reg).values() if any(on_soil_test_bound(b) for b in hits))


# An axis whose held-out error the named terms make worse: its RMSE rises and its mean |error| by more
# than this share (a compaction acting on x only was named as the catalogue's, which acts on both
# axes: z's mean |error| 41 -> 96 N while x's fell 906 -> 98 N; a term that leaves an axis as it was
# moves its mean |error| by a few %).
WORSE_AXIS_SHARE = 0.25


def _worse_axes(test: dict) -> list[tuple[str, tuple[float, float, float, float]]]:
    """[(axis, (RMSE before, after, mean |error| before, after) [N])] of the axes the named terms make
    worse on the held-out episodes (WORSE_AXIS_SHARE)."""
    b, a = test["before"], test["after"]
    out = []
    for axis in ("x", "z"):
        values = [b.get(f"rmse_{axis}"), a.get(f"rmse_{axis}"), b.get(f"mae_{axis}"), a.get(f"mae_{axis}")]
        if any(v is None for v in values):
            continue
        rb, ra, mb, ma = (float(v) for v in values)
        if ra > rb and ma > (1.0 + WORSE_AXIS_SHARE) * mb:
            out.append((axis, (rb, ra, mb, ma)))
    return out


def _soil_test_hint(rows: list[dict], advice: str = "; soil tests (--soil-tests) tell") -> str:
    """``advice`` to give soil tests, or, where each of the groups ``rows`` had them, what they leave
    open (an outside reader's run with --soil-tests was told to give them), or, where none of them
    has a soil label a test could match (bags without one, grouped by γ), that (such a run was told
    to give --soil-tests, which it refuses)."""
    if rows and all(r.get("tested_parameters") for r in rows):
        return "; the soil tests given bound θ only where they test it (a test of δ, or a narrower one, tells more)"
    if rows and not any(r.get("testable", True) for r in rows):
        return ("; a soil test would tell, but --soil-tests holds a group by its one soil label, which these groups "
                "lack (bags without a label, or grouped by γ; --group-by auto groups labelled bags by their label)")
    return advice


def _group_rows(reg: dict | None) -> list[dict]:
    """The θ-group rows of ``regimes.group_misfit`` in ``reg`` ([] without)."""
    return [r for r in ((reg or {}).get("misfit") or {}).get("rows", []) if r["kind"] == "group"]


def _off_label_text(reg: dict | None, beside_terms: bool = False) -> str:
    """Where the fitted soils lie outside their labels' textbook ranges: with nothing else wrong in the
    forces, θ may have taken an effect in (a drag ∝ d^1.5 of 47 % of the FEE force read as "no
    significant discrepancy" with clays fitted at φ 35°). ``beside_terms``: the soils fitted beside
    named terms, which then may be stand-ins whose θ took in the rest of an effect (an outside
    reader's z force ∝ √d named as a constant, "pinned down" among the library's forms, "explained",
    with loose sand fitted at φ 21° for 28°). Not a group cut at one depth (``one_depth``): there φ and
    c trade off along a ridge, and its θ lies anywhere on it with nothing missing."""
    rows = _group_rows(reg)
    off = [r for r in rows if r.get("theta_off_label") and not r.get("one_depth")]
    if not off:
        return ""
    shown = "; ".join(f"{r['name']}: {', '.join(r['theta_off_label'])}" for r in off[:3]) + ("; …" if len(off) > 3 else "")
    what = ("the named terms may be stand-ins, θ taking in the rest of an effect whose own form the library does "
            "not hold, which the forces alone cannot tell from another soil" if beside_terms else
            "θ may have taken in a missing effect, which the forces alone cannot tell from another soil")
    return (f"; but the {'soil fitted beside them' if beside_terms else 'fitted soil'} lies outside its label's textbook "
            f"range in {len(off)}/{len(rows)} groups ({shown}): {what}, or the soils are unlike the textbook's"
            + _soil_test_hint(off))


def _rarely(chance: float) -> str:
    """How often something happens by chance, in words: "in 2.8 % of cases", "in under 0.01 % of cases"."""
    if chance < 1e-4:
        return "in under 0.01 % of cases"
    return f"in {100 * chance:.2g} % of cases" if chance < 0.1 else f"in {100 * chance:.0f} % of cases"


def bound_hits_by_chance(reg: dict | None) -> float:
    """The chance that at least as many θ-groups as in ``reg`` sit on a soil test's bound with every
    test right and nothing missing from the model: each group lands on a bound as often as one of
    its n tested parameters' truth lies outside its interval, 1 − (1 − OUTSIDE_BY_CHANCE)^n, the
    groups independently (a Poisson-binomial tail). 1.0 with none on a bound, and where a row does not
    say how many parameters its tests bound (a report written before it did): nothing is claimed."""
    rows = _group_rows(reg)
    held = _on_test_bounds(reg)
    if not held or any("tested_parameters" not in r for r in rows):
        return 1.0
    counts = np.zeros(len(rows) + 1)
    counts[0] = 1.0
    for r in rows:  # the distribution of the number of groups on a bound, one group at a time
        p = 1.0 - (1.0 - OUTSIDE_BY_CHANCE) ** int(r.get("tested_parameters", 0))
        counts[1:] = counts[1:] * (1.0 - p) + counts[:-1] * p
        counts[0] *= 1.0 - p
    return float(min(1.0, counts[held:].sum()))


def _left_text(reg: dict | None) -> str:
    """What is left: the residual's RMS per axis and how much of it is its fast, noise-like part."""
    if not reg or not reg.get("fast_rms_n") or reg["fast_rms_n"].get("x") is None:
        return ""
    rms, fast = reg["rms_n"], reg["fast_rms_n"]
    parts = []
    for a in ("x", "z"):
        if fast[a] > rms[a]:  # successive ticks anti-correlated: an oscillation at the tick rate, not white noise
            parts.append(f"{a} {rms[a]:.0f} N, alternating from tick to tick ({fast[a]:.0f} N as white noise would: "
                         "an oscillation, e.g. a gate that flickers)")
        else:
            parts.append(f"{a} {rms[a]:.0f} N, of which tick-to-tick noise-like {fast[a]:.0f} N (slow structure "
                         f"{math.sqrt(rms[a] ** 2 - fast[a] ** 2):.0f} N)")
    return "; left: residual RMS " + "; ".join(parts)


def _untested_text(test: dict | None) -> str:
    """Where the baseline fits worse (``regimes.misfit_discrepancy``) but the held-out test part holds
    none of its episodes (``test['fits_worse_untested']``: the test's figures say nothing there), or
    the selection part none (``'fits_worse_unselected'``: no term was chosen on them)."""
    untested = (test or {}).get("fits_worse_untested") or []
    unselected = (test or {}).get("fits_worse_unselected") or []
    parts = []
    if untested:
        parts.append(f"the held-out test part holds no episode of {', '.join(untested)}, where the baseline fits worse: "
                     "its figures cannot judge an effect there")
    if unselected:
        parts.append(f"the selection part holds no episode of {', '.join(unselected)}, where the baseline fits worse: "
                     "no term was chosen on them")
    return f"; but {'; and '.join(parts)} (another --seed splits the groups otherwise)" if parts else ""


def misfit_text(reg: dict | None, quiet: bool = False) -> str:
    """Where the model fits worse (``regimes.group_misfit``) and where θ sits on its box, for the verdict.

    A group that fits worse is not a regime bias (θ per group absorbs a bias); with no flagged
    regime (``quiet``) it is said as a caution, never as a verdict: two soils of one γ sharing a θ
    (bags without a soil label) fit worse for no missing effect."""
    mis = (reg or {}).get("misfit")
    if not mis:
        return ""
    parts = [f"{misfit_unit_name(r)} ({r['ratio']:.1f}× the other episodes' relative misfit)" for r in flagged_rows(mis)]
    bound = [r for r in mis["rows"] if r["kind"] == "group" and r["theta_at_bound"]]
    n_groups = sum(1 for r in mis["rows"] if r["kind"] == "group")
    text = ""
    if parts:
        text += ("; " if not quiet else "; but ") + "the model fits worse in " + ", ".join(parts)
        text += " (an effect that acts there, or a form θ cannot follow there)" if not quiet else ""
        # (all bags unlabelled: "γ≈16 kN/m³"; beside labelled ones: "unknown γ≈16 kN/m³")
        by_gamma = [n for n in mis["groups"] if GAMMA_GROUP_PREFIX in str(n)]
        if by_gamma:  # bags without soil labels: a γ group may be two soils, which one θ cannot fit
            text += (f" ({', '.join(by_gamma)} is a group by unit weight: soils of one γ share one θ there and fit "
                     "worse with no effect missing; soil labels in the bags' metadata tell them apart)")
    for tested, one, why in (
            (False, False, "the model needs a soil outside the physical range there"),
            (False, True, f"each of them cut at one depth (its ticks within {100 * ONE_DEPTH_SPAN_M:g} cm), where φ and c "
                          "trade off along a ridge and θ slides to its box with nothing missing: that says nothing about "
                          "the physics; cuts at other depths (or soil tests) tell"),
            (True, None, "the forces want a soil outside the soil tests' intervals there: an effect θ "
                         "would take in without the tests, or a test that is off (by chance "
                         f"{100 * OUTSIDE_BY_CHANCE:.0f} % of the parameters tested at ± {WIDTH_SIGMA:g} std are)")):
        rows_b = [r for r in bound if any(on_soil_test_bound(b) == tested for b in r["theta_at_bound"])
                  and (one is None or bool(r.get("one_depth")) == one)]
        if rows_b:
            which = sorted({b for r in rows_b for b in r["theta_at_bound"] if on_soil_test_bound(b) == tested})
            text += (f"; θ on {'its soil test' if tested else 'its fit box'} in {len(rows_b)}/{n_groups} groups "
                     f"({', '.join(which)}: {', '.join(r['name'] for r in rows_b[:4])}{', …' if len(rows_b) > 4 else ''}), "
                     + why)
    return text
