"""``run_discrepancy``: measured episodes in, a verdict on the model's missing physics out.

1. fit        θ per θ-group fitted to the measured force; residual r = F_meas − F_model
2. regimes    residuals by depth, speed, v_z, Q, time, distance, soil, I_d; episode-level tests
3. candidates every catalogue term cross-validated across groups; greedy forward selection.
              If the baseline residual has structure, the few candidates of a sparse regression
              over a library of forms (``forms``) join the catalogue's in the same held-out test;
              what the named terms leave is searched again (3b). A form is named only if the
              held-out test groups (5) confirm it; else it is reported as tentative.
              Each named term then faces the library's forms in its place: one whose rivals fit
              as well is named with them (not pinned down), one they beat is called a stand-in.
4. model      the accepted terms with their k: ``AugmentedFEE`` and the simulator plugin specs
5. gap        held-out test groups (never used in 3): force error before/after

The held-out test part is split off first (by θ-group, stratified by soil, seeded); step 3
sees only the selection part. Step 2 describes every episode with the initial model
(the report's "baseline": the FEE plus any accepted terms, before the workflow adds one).
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from soil_physics import force_terms, term_forms
from soil_physics.term_forms import PREFIX as FORM_PREFIX
from soil_physics.augmented_fee import AugmentedFEE, plugin_spec

from pinn_estimator.classical import default_workers
from soil_msgs_py.episode import world_modes
from soil_msgs_py.params import MAX_PLAUSIBLE_FORCE_N
from .candidates import (FOLDS, HOLDOUT_SHARE, MAX_TERMS, MIN_GAIN, check_holdout, paired_test, select_terms,
                         split_holdout)
from .forms import describe_form, pin_kind, rival_forms, search_forms, weaker_pin
from .fee_fit import fit_fixed, fit_joint, residuals
from .frame import (DEFAULT_STRIDE, MIN_CUT_S, MIN_DEPTH_M, SKIP_S, Frame, build_frame, check_frame_settings, folded_rms,
                    folded_vibration)
from .gap import NO_WORSE_WITHOUT, compare_predictions, confirmation, depth_forecast_gap, fee_gap
from .provenance import environment
from .regimes import (ALPHA, MIN_EFFECT, bin_edges, flagged_units, group_misfit, holm, misfit_discrepancy,
                      misfit_unit_name, regime_analysis, time_in_soil_is_clock, travel_is_position,
                      travel_is_speed_times_time, unit_episodes, variable_labels)
from .soil_tests import displayed_box, hold_theta, unmatched
from .verdict import fmt_n, forecast_gap_text, theta_shift, verdict_of

REPORT_VERSION = 1


def load_frame(bag_dir, *, stride: int = DEFAULT_STRIDE, group_by: str = "auto", cache: bool = True, workers: int = 1,
               skip_bad_bags: bool = False) -> Frame:
    """Read a directory of episode bags (``load_dataset``) into the analysis frame."""
    from pinn_estimator.dataset import load_dataset

    ds = load_dataset(bag_dir, cache=cache, workers=workers, skip_bad_bags=skip_bad_bags)
    return build_frame(ds, stride=stride, group_by=group_by)


def fold_text(frame: Frame, min_effect: float, *, rebuilt: bool) -> str:
    """What the verdict says where one analysed tick in ``frame.stride`` folds a vibration into a slow
    signal (``frame.folded_vibration``): the frame is built again at every tick (``rebuilt``), or, for
    a frame given ready-made, the user is told to; "" where nothing folds."""
    folded = folded_vibration(frame, min_effect)
    if not folded:
        return ""
    n, fast = frame.stride, frame.fast_force
    what = ", ".join(f"{a} {folded_rms(fast, a):.0f} N" for a in folded)
    measured = ", ".join(f"{a} {fast['within'][a]:.0f} within, {fast['between'][a]:.0f} between" for a in folded)
    head = (f"analysed every tick, not one in {n}" if rebuilt else
            f"the frame given analyses one tick in {n}, which may fold a vibration into a slow signal: build it with "
            "stride 1")
    return (f"{head}: within each {n} ticks the force varies beyond noise by RMS {what} (RMS {measured} analysed ticks), "
            f"a vibration that one tick in {n} would fold into a slow signal")


def _refuse_non_finite(r0: np.ndarray, model: AugmentedFEE) -> None:
    """ValueError if the baseline's residual RMS (NaN ticks, where the model is undefined, left
    out) is not finite or beyond any soil's force (``MAX_PLAUSIBLE_FORCE_N``): an accepted term
    with a k far too large (soil_inertia=1e200) overflows the force, at 1e150 it reports 2e152 N
    of residual, and every figure after it would be garbage (the report's RMS null)."""
    with np.errstate(over="ignore", invalid="ignore"):
        rms = np.sqrt(np.nanmean(np.square(r0), axis=0))
    bad = [f"{axis} {v:.3g} N" for axis, v in zip(("x", "z"), rms) if not (np.isfinite(v) and v <= MAX_PLAUSIBLE_FORCE_N)]
    if bad:
        given = ", ".join(f"{name}={k:g}" for name, k in model.terms)
        raise ValueError(f"the baseline model's residual RMS ({', '.join(bad)}) is not a finite force of at most "
                         f"{MAX_PLAUSIBLE_FORCE_N:.3g} N"
                         + (f" with the accepted term(s) {given}: is a k far too large?" if given else ""))


def run_discrepancy(bag_dir=None, out_dir=None, *, frame: Frame | None = None, dataset=None, terms=None,
                    accepted=(), holdout: float = HOLDOUT_SHARE, folds: int = FOLDS, seed: int = 0,
                    stride: int = DEFAULT_STRIDE, alpha: float = ALPHA, min_gain: float = MIN_GAIN,
                    min_effect: float = MIN_EFFECT,
                    group_by: str = "auto", allow_negative_k: bool = False, workers: int | None = None,
                    predictors=None, cache: bool = True, skip_bad_bags: bool = False,
                    plots: bool = True, forms: bool = True, user_terms=(), soil_tests=(), log=print) -> dict:
    """The whole workflow on a bag directory (or a ``Dataset``/``Frame``); returns the report dict.

    terms: candidate term names (default: the whole catalogue); accepted: terms already in the
    model, (name, k) pairs or 'name=k' (their k stays fixed); holdout: share of θ-groups held
    out for the before/after test; folds: cross-validation folds over the selection groups;
    stride: every stride-th analysed tick; alpha: significance level (Holm-corrected);
    min_gain: least share of held-out error a term must remove; min_effect: least |bias| as a
    share of |F| for a regime to be flagged; group_by: 'auto' (soil name + I_d of the
    metadata share θ; bags without any soil label: as 'gamma', see ``build_frame``), 'episode'
    or 'gamma' (the same measured γ shares θ); allow_negative_k: let k take the sign opposite to the
    term's physics (default: k >= 0); predictors: the hook for other models' before/after
    (e.g. the PINN): {label: fn(test_frame, model_before, model_after, context)} where context
    = {'dataset', 'selection_episodes', 'test_episodes', 'seed', 'edges', 'workers'} (episode
    names; the named terms' k was fitted on the selection episodes only; 'edges': the regime
    bins; 'workers': the processes this run may use) and fn
    returns either (F_before, F_after), predictions (N, 2) [N] of the soil's force at ``test_frame``'s ticks
    (``test_frame.rows`` index the Dataset; scored by ``gap.compare_predictions`` against
    ``test_frame.forces``, the measured force less the blade's inertia ``test_frame.inertia``: a model
    of the measured force subtracts it), or a finished result dict
    that is stored as it is. skip_bad_bags: leave out (and report) bags that cannot be read instead of
    stopping at the first, naming it (``load_dataset``). forms: when the residual has regime structure,
    search the library of forms (``forms.search_forms``) and test its candidates beside the catalogue
    terms (named only if the held-out test groups confirm them). user_terms: more
    candidate term names (e.g. forms from an earlier run's ``discovered_terms.yaml``, ``forms.load_catalogue``),
    tested like catalogue terms. soil_tests: ``soil_tests.SoilTest`` entries (``load_soil_tests``): θ of a
    group whose soil label they match moves only within the test's interval (an effect θ would absorb is
    then left in the residual).
    Writes discrepancy.md/.json and PNGs to ``out_dir`` when given. ValueError on bad input.
    """
    t0 = time.perf_counter()
    say = log or (lambda *_: None)
    workers = default_workers() if workers is None else max(1, int(workers))
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha={alpha} must be in (0, 1)")
    if folds < 2:
        raise ValueError(f"folds={folds} must be >= 2")
    if not 0.0 <= min_gain < 1.0:
        raise ValueError(f"min_gain={min_gain} must be in [0, 1)")
    check_holdout(holdout)  # (the split and the frame check these too, but only after the bags are read)
    folded_note = ""  # the frame analyses every tick, where every stride-th would fold a vibration (``folded_vibration``)
    if frame is None:
        check_frame_settings(stride, group_by)
    initial = AugmentedFEE(accepted)
    candidates = _candidates(terms, initial)
    candidates += [n for n in dict.fromkeys(user_terms or ()) if n not in candidates and n not in initial.names]
    if frame is None:
        if dataset is None:
            if bag_dir is None:
                raise ValueError("give a bag directory, a Dataset or a Frame")
            say(f"reading {bag_dir} ...")
            from pinn_estimator.dataset import load_dataset

            dataset = load_dataset(bag_dir, cache=cache, workers=workers, skip_bad_bags=skip_bad_bags)
        frame = build_frame(dataset, stride=stride, group_by=group_by)
        if folded_note := fold_text(frame, min_effect, rebuilt=True):
            say(folded_note)
            frame = build_frame(dataset, stride=1, group_by=group_by)
        source = str(bag_dir if bag_dir is not None else getattr(dataset, "root", ""))
    else:
        source = frame.source
        stride = frame.stride  # (the frame given is analysed as it was built)
        if folded_note := fold_text(frame, min_effect, rebuilt=False):
            say(f"warning: {folded_note}")
    if soil_tests:
        frame = hold_theta(frame, soil_tests)
        say(f"soil tests hold θ in {len(frame.theta_boxes)} of {len(frame.groups)} θ-groups")
        if idle := unmatched(frame, soil_tests):
            say(f"warning: soil test(s) {', '.join(idle)} hold no θ-group: no episode of one soil label matches "
                "them (a soil name or density mistyped?), or a test of its density wins there")
    n_ep = len(frame.episodes)
    say(f"{n_ep} episodes, {len(frame.groups)} θ-groups ({_grouping(frame)}), "
        f"{len(frame)} ticks (stride {frame.stride})")
    for names, why in _left_out(frame):
        say(f"left out {len(names)} episode(s): {why}: {', '.join(names[:5])}{' …' if len(names) > 5 else ''}")

    # 1. the initial model's θ on every group (per-group fits are independent of each other)
    with np.errstate(over="ignore"):  # an accepted k far too large overflows: _refuse_non_finite says so
        base = fit_fixed(frame, initial)
    r0, _ = residuals(frame, initial, base)
    _refuse_non_finite(r0, initial)
    failed = [frame.group_names[g] for g, ok in base.success.items() if not ok]
    edges = bin_edges(frame)
    # 2. where they disagree
    reg0 = regime_analysis(frame, r0, edges=edges, alpha=alpha, min_effect=min_effect)
    reg0["misfit"] = group_misfit(frame, r0, alpha=alpha, theta_table=base.table(frame))
    reg0["travel_is_speed_times_time"] = travel_is_speed_times_time(frame)
    reg0["travel_is_position_m"] = travel_is_position(frame)
    reg0["time_in_soil_is_clock_s"] = time_in_soil_is_clock(frame)
    say(f"baseline residual RMS x {reg0['rms_n']['x']:.0f} N, z {reg0['rms_n']['z']:.0f} N; "
        f"flagged regimes: {', '.join(reg0['flagged_variables']) or 'none'}; fits worse in: "
        f"{', '.join(flagged_units(reg0['misfit'])) or 'no group'}")
    # 3. name the missing effect, on the selection part only
    sel_groups, test_groups = split_holdout(frame, holdout, seed)
    fsel = frame.select(groups=sel_groups)
    # the baseline's residual has structure (or some soils fit worse by a form θ cannot follow there):
    # library forms join the catalogue from the first round, so a catalogue term is named only if no
    # form beats it on held-out groups
    form_report = None
    pool = list(candidates)
    worse_rows = misfit_discrepancy(reg0)
    fits_worse = [misfit_unit_name(r) for r in worse_rows]
    if forms and (reg0["significant"] or fits_worse):
        first = search_forms(fsel, initial, base, folds=folds, catalogue=candidates, log=say)
        form_report = {"searched": True, "residual_structure": reg0["flagged_variables"], "fits_worse_in": fits_worse,
                       "search": first}
        pool += [n for n in first["candidates"] if n not in pool]
    sel = select_terms(fsel, initial, base, pool, folds=folds, seed=seed, alpha=alpha, min_gain=min_gain,
                       workers=workers, allow_negative_k=allow_negative_k, log=say)
    for rnd in sel["rounds"]:
        rnd["stage"] = "catalogue + forms" if form_report else "catalogue"
    # 3a. a form won the first round: a form is for what the catalogue's mechanisms cannot explain
    # together, and greedy selection sees one term at a time (soil inertia and compaction hidden at
    # once: one form mimicking both took 80 % of the error against compaction's 65 %, after which
    # neither catalogue term passed, where the two together took more)
    if form_report is not None and sel["accepted"] and sel["accepted"][0].name.startswith(FORM_PREFIX):
        sel = _catalogue_path(sel, form_report, fsel, initial, base,
                              [n for n in candidates if not n.startswith(FORM_PREFIX)], say,
                              folds=folds, seed=seed, alpha=alpha, min_gain=min_gain, workers=workers,
                              allow_negative_k=allow_negative_k)
    final: AugmentedFEE = sel["model"]
    new_terms = [s for s in sel["accepted"]]
    # 3b. what the named terms leave: its form, searched again on the augmented model's residual
    if forms and new_terms and len(new_terms) < MAX_TERMS:
        left = regime_analysis(fsel, residuals(fsel, final, sel["fit"])[0], edges=edges, alpha=alpha,
                               min_effect=min_effect)
        form_report = {**(form_report or {}), "searched_after": bool(left["significant"]),
                       "residual_structure_after": left["flagged_variables"]}
        if left["significant"]:
            found = search_forms(fsel, final, sel["fit"], folds=folds,
                                 catalogue=[n for n in candidates if n not in final.names], log=say)
            form_report["search_after"] = found
            fresh = [n for n in found["candidates"] if n not in final.names]
            if fresh:  # the catalogue's remaining terms were scored against this model in the last round above
                sel2 = select_terms(fsel, final, sel["fit"], fresh, folds=folds, seed=seed,
                                    alpha=alpha, min_gain=min_gain, max_terms=MAX_TERMS - len(new_terms),
                                    workers=workers, allow_negative_k=allow_negative_k, log=say)
                for rnd in sel2["rounds"]:
                    rnd["stage"] = "forms"
                sel["rounds"] += sel2["rounds"]
                new_terms += sel2["accepted"]
                final, sel["fit"] = sel2["model"], sel2["fit"]
    if form_report is not None:
        form_report["discovered"] = [describe_form(fsel, sel["fit"], s.to_dict()) for s in new_terms
                                     if s.name.startswith(FORM_PREFIX)]
    # 5a. the gap on the held-out test groups (never used above): the force error, and the
    # planner's question, the force at another depth from a fit at one depth
    test = test_arrays = ftest = None
    blind: dict[str, list[str]] = {}
    if test_groups:
        ftest = frame.select(groups=test_groups)
        test, test_arrays = _held_out(ftest, initial, final, base, edges)
        # where the baseline fits worse but the held-out part holds no episode: its test cannot judge
        # an effect there (an outside reader's drag in the loose soils, none of them held out: "neither
        # ... explains it on held-out episodes", whose error was the control's to the newton); or the
        # selection part none: no term was chosen on them
        held, chosen_on = {int(e) for e in ftest.episodes}, {int(e) for e in fsel.episodes}
        members = {misfit_unit_name(r): unit_episodes(frame, r) for r in worse_rows}
        blind = {"fits_worse_untested": [n for n, eps in members.items() if not eps & held],
                 "fits_worse_unselected": [n for n, eps in members.items() if not eps & chosen_on]}
        forms_in = [s for s in new_terms if s.name.startswith(FORM_PREFIX)]
        if forms_in and not _confirmed(test, min_gain, alpha):
            # a form from a library of hundreds is a claim only if the test episodes confirm it: the
            # set failed, so each form on its own beside the named catalogue terms
            catalogue_model = AugmentedFEE([t for t in final.terms if not t[0].startswith(FORM_PREFIX)])
            k_of = dict(final.terms)
            marginal = {}
            for s in forms_in:
                marginal[s.name] = _held_out(ftest, catalogue_model, catalogue_model.with_term(s.name, k_of[s.name]), base, edges)[0]
            # the held-out episodes now choose among forms: their forecast p-values are Holm-corrected
            p_fc = holm([(t["depth_forecast"] or {}).get("p_paired", 1.0) for t in marginal.values()])
            for (name, t1), p_h in zip(list(marginal.items()), p_fc):
                t1["depth_forecast"] = {**t1["depth_forecast"], "p_paired": float(p_h)}
                marginal[name] = {"confirmed": _confirmed(t1, min_gain, alpha), **_confirmation(t1, min_gain, alpha)}
            kept = [s for s in forms_in if marginal[s.name]["confirmed"]]
            trial = catalogue_model
            if kept:  # the forms confirmed on their own, their k refitted without the others (selection part),
                # judged together against the catalogue terms alone (not the initial model: the
                # catalogue's own gain must not carry them)
                trial, kept, _ = _refitted_if_confirmed(fsel, ftest, catalogue_model, kept, sel["fit"], base, edges,
                                                        min_gain, alpha, allow_negative_k)
            dropped = [s for s in forms_in if s.name not in {k.name for k in kept}]
            say(f"the accepted form(s) together are not confirmed on the held-out test episodes (RMSE "
                f"{fmt_n(test['before']['rmse'])} -> {fmt_n(test['after']['rmse'])} N, force at another depth {forecast_gap_text(test)})"
                + (f"; not named: {', '.join(s.name for s in dropped)}" if dropped else "")
                + (f"; confirmed on their own and refitted: {', '.join(s.name for s in kept)}" if kept else ""))
            form_report["not_confirmed"] = {"forms": [s.name for s in dropped], **_confirmation(test, min_gain, alpha),
                                            "each_form": marginal}
            _mark_confirmed(form_report, kept)
            new_terms = [s for s in new_terms if not s.name.startswith(FORM_PREFIX)] + kept
            final = trial  # the catalogue terms and the kept forms, refitted
            test, test_arrays = _held_out(ftest, initial, final, base, edges)
        else:
            for d in (form_report or {}).get("discovered") or []:
                d["confirmed"] = True
    # 5a'. a catalogue name faces the test a form does: named terms the held-out test episodes do
    # not confirm (cross-validation on the selection part chose them, the held-out part disagrees)
    # are reported as tentative and named nowhere; a verdict never rests on them. Forms that the
    # held-out episodes confirm without the catalogue terms (refitted alone) stay named.
    tentative = None
    if test is not None and new_terms and not _confirmed(test, min_gain, alpha):
        forms_named = [s for s in new_terms if s.name.startswith(FORM_PREFIX)]
        alone, kept_forms, judged = initial, [], None
        if forms_named and len(forms_named) < len(new_terms):
            alone, kept_forms, judged = _refitted_if_confirmed(fsel, ftest, initial, forms_named, sel["fit"], base,
                                                               edges, min_gain, alpha, allow_negative_k)
        demoted = [s for s in new_terms if s.name not in {f.name for f in kept_forms}]
        tentative = {"terms": [_term_row(s) for s in demoted], **_confirmation(test, min_gain, alpha)}
        say(f"the named term(s) {', '.join(s.name for s in demoted)} are not confirmed on the held-out test episodes "
            f"(RMSE {fmt_n(test['before']['rmse'])} -> {fmt_n(test['after']['rmse'])} N, force at another depth "
            f"{forecast_gap_text(test)}): tentative, not named"
            + (f"; confirmed without them: {', '.join(s.name for s in kept_forms)}" if kept_forms else ""))
        _mark_confirmed(form_report, kept_forms)
        new_terms, final = kept_forms, alone  # alone: the initial model unless forms were kept
        test, test_arrays = judged or _held_out(ftest, initial, final, base, edges)
    # 5a''. each of several named terms must earn its place on the held-out test episodes: a set they
    # confirm can carry a term that does nothing there, or harm, beside the others (a catalogue term
    # that mimics part of another effect's depth profile). Backward elimination: the term whose
    # removal helps most, if removing it leaves both the held-out force error and the forecast at
    # another depth no worse, is tentative; the rest are refitted without it and judged again as a
    # set; repeat. A term whose force on the held-out ticks is negligible is not judged there (its
    # regime may be absent from the held-out groups).
    while test is not None and len(new_terms) >= 2:
        places = {s.name: _place(ftest, final, s.name, base, edges, min_gain) for s in new_terms}
        idle = [s for s in new_terms if places[s.name]["judged"] and not places[s.name]["earns"]]
        if not idle:
            break
        worst = min(idle, key=lambda s: places[s.name]["gain"])
        rest = [s for s in new_terms if s.name != worst.name]
        trial, kept, judged = _refitted_if_confirmed(fsel, ftest, initial, rest, sel["fit"], base, edges,
                                                     min_gain, alpha, allow_negative_k)
        failed = [s for s in rest if s.name not in {k.name for k in kept}]
        say(f"held-out test, term by term: removing {worst.name} leaves {NO_WORSE_WITHOUT}: tentative"
            + (f"; the rest, refitted without it, not confirmed: {', '.join(s.name for s in failed)}" if failed else ""))
        rows = [_term_row(worst, why="idle")] + [_term_row(s, why="set") for s in failed]
        if tentative is None:
            tentative = {"terms": [], **_confirmation(test, min_gain, alpha)}
        tentative["terms"] += rows
        new_terms, final = kept, trial
        test, test_arrays = judged or _held_out(ftest, initial, final, base, edges)
        _mark_confirmed(form_report, [s for s in kept if s.name.startswith(FORM_PREFIX)])
    # 4. the augmented model on every episode
    reg1, r1, pins, theta1 = None, None, {}, None
    if new_terms:
        fit1 = fit_fixed(frame, final, base.merged(sel["fit"]))
        theta1 = fit1.table(frame)
        r1, _ = residuals(frame, final, fit1)
        reg1 = regime_analysis(frame, r1, edges=edges, alpha=alpha, min_effect=min_effect)
        reg1["misfit"] = group_misfit(frame, r1, alpha=alpha, theta_table=theta1)
        # 5a'''. a named term is a claim about the mechanism only if these data pin its form down: every
        # other form of the library, in its place, fits what it takes significantly worse, on the
        # held-out test part (where the term was confirmed, and which chose nothing) and on the
        # selection part (where it is favoured, but twice as many episodes tell forms apart):
        # ``forms.weaker_pin``. θ per group is fitted group by group, so fit1 holds each part's fit.
        if forms:
            parts = [(ftest, "held-out test")] if ftest is not None else []
            pins = _pin_down([*parts, (fsel, "selection")], final, fit1, new_terms, form_report, alpha)
    # 5b. other models' before/after on the held-out test groups
    arrays = {"frame": frame, "edges": edges, "r0": r0, "r1": r1}
    if test_groups:
        arrays.update(test_frame=ftest, test=test_arrays)
        if predictors:
            context = {"dataset": dataset, "selection_episodes": frame.episode_names(sel_groups),
                       "test_episodes": frame.episode_names(test_groups), "seed": seed, "edges": edges,
                       "workers": workers}
            test["predictors"] = {}
            for label, fn in dict(predictors).items():
                say(f"held-out comparison for {label} ...")
                got = fn(ftest, initial, final, context)
                if isinstance(got, dict):
                    test["predictors"][str(label)] = got
                else:
                    pb, pa = got
                    test["predictors"][str(label)] = compare_predictions(ftest, pb, pa, label=str(label), edges=edges)
    theta0 = base.table(frame)
    shift = theta_shift(theta0, theta1)
    if test is not None:  # the final held-out figures' (``test`` is recomputed as terms are judged)
        test.update(blind)
    # the user's catalogue: each term tested and the name they gave it (``forms.load_catalogue``)
    names_given = dict(user_terms) if isinstance(user_terms, dict) else {t: t for t in user_terms or ()}
    verdict, summary = verdict_of(new_terms, reg0, test, reg1, form_report, tentative, pins, shift,
                                  user_names=names_given)
    summary += f"; {folded_note}" if folded_note else ""
    say(summary)
    report = {
        "version": REPORT_VERSION,
        "source": source,
        "verdict": verdict,
        "summary": summary,
        "settings": {"holdout": holdout, "folds": folds, "seed": seed, "stride": frame.stride, "stride_asked": stride,
                     "folded_vibration": folded_note, "alpha": alpha,
                     "min_gain": min_gain, "min_effect": min_effect, "group_by": frame.group_by,
                     "candidates": candidates, "accepted_initial": [list(t) for t in initial.terms],
                     "allow_negative_k": allow_negative_k, "forms": forms, "min_depth_m": MIN_DEPTH_M, "skip_s": SKIP_S,
                     "workers": workers,
                     "user_terms": names_given},
        "data": {**_data_summary(frame, sel_groups, test_groups, soil_tests),
                 # the bags' world (metadata world_mode; "" for a machine's): the check against a hidden effect reads it
                 "world": next(iter(world_modes(getattr(dataset, "metas", ()))), ""),
                 "skipped_bags": [b["bag"] for b in getattr(dataset, "skipped", None) or []],
                 # sha256 of the bags' bytes ('' for data given in memory): same fingerprint, same data
                 "fingerprint": getattr(dataset, "fingerprint", "") or ""},
        "environment": environment(),
        "baseline": {"model": [list(t) for t in initial.terms], "theta": theta0,
                     "failed_groups": failed, "rms_n": reg0["rms_n"]},
        "regimes": reg0,
        "selection": {"rounds": sel["rounds"],
                      "accepted": [_term_row(s, pin=pins.get(s.name)) for s in new_terms],
                      "not_confirmed": tentative},
        "model": {"terms": [list(t) for t in final.terms], "plugin_specs": final.plugin_specs(),
                  "extra_term_args": final.extra_term_args(), "theta": theta1, "theta_shift": shift},
        "forms": form_report,
        "regimes_after": reg1,
        "test": test,
        "notes": _notes(frame, len(test_groups)),
        "variable_labels": variable_labels(),
    }
    report["run_time_s"] = round(time.perf_counter() - t0, 2)
    if out_dir is not None:
        from .report import write_outputs

        paths = write_outputs(report, out_dir, arrays if plots else None)
        report["outputs"] = [str(p) for p in paths]
        say(f"report: {Path(out_dir) / 'discrepancy.md'}")
    return report


def left_after(accepted) -> float:
    """The share of the cross-validated error a greedy path leaves: the product of (1 − gain) over its
    rounds (each round's gain is against the model of the round before, on the same folds)."""
    return float(math.prod(1.0 - s.gain for s in accepted))


def _catalogue_path(sel: dict, form_report: dict, fsel: Frame, initial: AugmentedFEE, base, mechanisms: list[str],
                    say, **select) -> dict:
    """``sel``, whose first round a form won, or the greedy path through the catalogue's terms alone
    where that leaves at most as much of the cross-validated error, or where the forms' path does
    not leave significantly less of it episode by episode (one-sided Wilcoxon at ``alpha``): ties,
    and differences within the noise, go to the mechanisms (a form that took 65 % off where the
    catalogue's term took 66 % had been named, a wrong name). Both paths are recorded in
    ``form_report['catalogue_path']`` and the rounds of the one not taken are kept for the
    report, marked so."""
    # none of them took min_gain off in the first round (beside the forms, on the same folds): their
    # path would name nothing (the unlabelled default world's best took 0.9 %)
    if not any(sc["name"] in mechanisms and sc["gain"] is not None and sc["gain"] >= select["min_gain"]
               for sc in sel["rounds"][0]["scores"]):
        return sel
    alt = select_terms(fsel, initial, base, mechanisms, log=say, **select)
    left_forms, left_catalogue = left_after(sel["accepted"]), left_after(alt["accepted"])
    p_forms = (paired_test(alt["accepted"][-1].mse_after, sel["accepted"][-1].mse_after)
               if alt["accepted"] and sel["accepted"] else 0.0)  # forms' per-episode errors below the catalogue's
    chosen = ("catalogue" if alt["accepted"] and (left_catalogue <= left_forms or p_forms >= select["alpha"])
              else "forms")
    form_report["catalogue_path"] = {
        "forms_path": [s.name for s in sel["accepted"]], "forms_left": left_forms,
        "catalogue_path": [s.name for s in alt["accepted"]], "catalogue_left": left_catalogue, "chosen": chosen,
        "p_forms_better": p_forms}
    say(f"the catalogue's terms alone ({', '.join(s.name for s in alt['accepted']) or 'none'}) leave "
        f"{100 * left_catalogue:.0f} % of the cross-validated error, the path through the forms "
        f"({', '.join(s.name for s in sel['accepted'])}) {100 * left_forms:.0f} %: "
        + ("the catalogue's path is taken" if chosen == "catalogue" else "the forms' path stays")
        + (f" (the forms' errors are not significantly below its episode by episode, p = {p_forms:.2g})"
           if chosen == "catalogue" and left_catalogue > left_forms else ""))
    if chosen == "forms":
        return sel
    for rnd in sel["rounds"]:
        rnd["stage"] = "catalogue + forms: not taken, the catalogue's terms alone explain as much"
    for rnd in alt["rounds"]:
        rnd["stage"] = "catalogue alone: taken"
    return {**alt, "rounds": sel["rounds"] + alt["rounds"]}


def _candidates(terms, model: AugmentedFEE) -> list[str]:
    if terms is None:
        names = list(force_terms.CATALOGUE)
    else:
        if isinstance(terms, str):
            terms = [t for t in terms.split(",")]
        names = [t.strip() for t in terms if t and t.strip()]
        if not names:
            raise ValueError("terms: give at least one catalogue term name")
    for n in names:
        if "=" in n:
            raise ValueError(f"terms: {n!r} — candidate terms are names only (their k is fitted); give terms "
                             f"already in the model with a fixed k as accepted ('--accepted name=k')")
        force_terms.get_term(n)
    out = [n for n in dict.fromkeys(names) if n not in model.names]
    if not out:
        raise ValueError("every candidate term is already in the model (accepted)")
    return out


def _shared(frame: Frame) -> bool:
    return len(frame.groups) < len(frame.episodes)


def _grouping(frame: Frame) -> str:
    """What a θ-group is in this frame, for the report."""
    if frame.group_by == "gamma":
        return ("soil group (episodes of the same measured unit weight γ; no soil label read)" if _shared(frame)
                else "episode (every episode has its own γ; no soil label read)")
    if frame.unlabelled_by_gamma:
        return "soil group (metadata soil + I_d; measured γ for the episodes without a soil label)"
    return "soil group (metadata soil + I_d)" if _shared(frame) else "episode"


def _data_summary(frame: Frame, sel_groups, test_groups, soil_tests=()) -> dict:
    return {
        "episodes": int(len(frame.episodes)), "ticks": int(len(frame)), "theta_groups": int(len(frame.groups)),
        "theta_per": _grouping(frame),
        "metadata_soils": frame.has_metadata(),
        "left_out_changing_soil": list(frame.changing_soil),
        "left_out_too_short": list(frame.too_short),
        "left_out_copies": list(frame.copies),
        "selection_groups": [frame.group_names[g] for g in sel_groups],
        "test_groups": [frame.group_names[g] for g in test_groups],
        "selection_episodes": frame.episode_names(sel_groups), "test_episodes": frame.episode_names(test_groups),
        # soil tests holding θ: group -> [[lo, hi] per φ [°], c [Pa], δ [°]] (None: that parameter free)
        "soil_tests": {frame.group_names[g]: displayed_box(lo, hi) for g, (lo, hi) in sorted((frame.theta_boxes or {}).items())},
        "soil_tests_unmatched": unmatched(frame, soil_tests) if soil_tests else [],
    }


def _notes(frame: Frame, n_test_groups: int) -> list[str]:
    label = ("no soil label (episodes grouped by their measured γ)" if frame.group_by == "gamma"
             else "the metadata soil name/I_d (a grouping label only)")
    if frame.unlabelled_by_gamma:
        label += (f"; the {len(frame.unlabelled_by_gamma)} episode(s) without a soil label grouped by their "
                  "measured γ")
    notes = [
        "Ground truth (/soil/ground_truth, Dataset.truth) and the bag metadata's record of simulator "
        f"effects/plugins are never read; inputs are Θ_k, the measured force, time and {label}.",
        "Statistics are at the episode level (ticks within an episode are autocorrelated); p-values are "
        "Holm-corrected; k ± SE is the grouped jackknife over the cross-validation folds (statistical only, "
        "no model-form error).",
    ]
    if n_test_groups:
        notes.append("The held-out test episodes also choose among terms: each form alone when a named set "
                     "fails, and each of several named terms term by term; their figures are the confirmation "
                     "of that choice, not a test independent of it.")
    if not frame.has_metadata() and n_test_groups >= 2:
        notes.append("No soil label: the held-out test groups are drawn one from each band of measured γ "
                     "(as many bands as test groups), so the test part spans the soils' range.")
    if not _shared(frame):
        notes.append(
            "θ is fitted per episode (no shared soil label): an effect that is constant within an episode "
            "(speed- or depth-dependent terms at constant speed/depth) is absorbed by θ and cannot be detected; "
            "only effects that vary within an episode (e.g. with time or distance) can."
        )
    notes += [f"{len(names)} episode(s) left out: {why}." for names, why in _left_out(frame)]
    return notes


def _left_out(frame: Frame) -> list[tuple[tuple[str, ...], str]]:
    """(episode names, why) of each kind of episode the frame left out, for the log and the report."""
    kinds = ((frame.changing_soil, "their soil changes along the path (soil patches in the metadata), and one θ "
                                   "cannot hold across a change"),
             (frame.too_short, f"less than {MIN_CUT_S:g} s of the blade in the soil after the start transient, too "
                               "little to fit their soil to"),
             (frame.copies, "each is a copy of another episode analysed (the same metadata but the seed, the same "
                            "samples: the noise-free fee world's seeds, a replay recorded again), whose evidence it "
                            "would count twice"))
    return [(names, why) for names, why in kinds if names]


def _held_out(ftest: Frame, before: AugmentedFEE, after: AugmentedFEE, base, edges) -> tuple[dict, dict]:
    """``gap.fee_gap`` on the held-out groups with the force at another depth
    (``gap.depth_forecast_gap``) under "depth_forecast": what a confirmation is judged on."""
    test, arrays = fee_gap(ftest, before, after, base, edges=edges)
    test["depth_forecast"] = depth_forecast_gap(ftest, before, after)
    return test, arrays


def _confirmation(test: dict, min_gain: float, alpha: float) -> dict:
    """The held-out figures a confirmation is judged on (``gap.confirmation``), with the rule's
    ``min_gain`` and ``alpha``, so that a report says why they did not confirm."""
    fc = test.get("depth_forecast") or {}
    return {"sse_reduction": test["sse_reduction"], "test_rmse_before": test["before"]["rmse"],
            "test_rmse_after": test["after"]["rmse"], "forecast_reduction": fc.get("reduction"),
            "forecast_p": fc.get("p_paired"), "forecast_pct_before": (fc.get("before") or {}).get("vector_pct"),
            "forecast_pct_after": (fc.get("after") or {}).get("vector_pct"), "min_gain": min_gain, "alpha": alpha}


def _confirmed(test: dict, min_gain: float, alpha: float) -> bool:
    """Held-out test episodes confirm the named terms (``gap.confirmation``)."""
    fc = test.get("depth_forecast") or {}
    return confirmation(test["sse_reduction"], fc.get("reduction"), fc.get("p_paired", 1.0), min_gain, alpha)[0]


# A term whose force on the held-out ticks has an RMS below this share of their mean |F| cannot be
# judged there (its regime, e.g. one soil, may be absent from the held-out groups).
MIN_JUDGED_SHARE = 0.01


def _place(ftest: Frame, model: AugmentedFEE, name: str, base, edges, min_gain: float) -> dict:
    """Does term ``name`` earn its place in ``model`` on the held-out test episodes? Removed (the others'
    k as they are, θ refitted per held-out group), {'judged': its force there is not negligible,
    'earns': the force error gets worse without it, or the forecast at another depth by >= ``min_gain``,
    'gain': the force error's SSE reduction it brings}."""
    without = AugmentedFEE([t for t in model.terms if t[0] != name])
    test, arrays = _held_out(ftest, without, model, base, edges)
    change = arrays["after"][0] - arrays["before"][0]
    change = change[np.isfinite(change).all(1)]
    fmag = float(np.mean(np.hypot(ftest.forces[:, 0], ftest.forces[:, 1])))
    judged = len(change) > 0 and math.sqrt(float(np.mean((change ** 2).sum(1)))) >= MIN_JUDGED_SHARE * fmag
    gain = test["sse_reduction"]
    red = (test.get("depth_forecast") or {}).get("reduction")
    earns = (gain is not None and gain > 0.0) or (red is not None and red >= min_gain)
    return {"judged": bool(judged), "earns": bool(earns), "gain": -math.inf if gain is None else float(gain)}


def _refitted_if_confirmed(fsel: Frame, ftest: Frame, reference: AugmentedFEE, terms, start, base, edges,
                           min_gain: float, alpha: float, allow_negative_k: bool):
    """``terms`` added to ``reference`` one after another, each k fitted jointly with θ on the
    selection part, then judged together against ``reference`` on the held-out test episodes:
    (the model with them, the terms with their refitted k, ``_held_out`` of reference vs that model)
    if confirmed, else (reference, [], None)."""
    model = reference
    for s in terms:
        fit_k = fit_joint(fsel, model, s.name, start, allow_negative_k=allow_negative_k)
        model, start = model.with_term(s.name, float(fit_k.k)), fit_k
    judged = _held_out(ftest, reference, model, base, edges)
    if not _confirmed(judged[0], min_gain, alpha):
        return reference, [], None
    k_new = dict(model.terms)
    return model, [dataclasses.replace(s, k=k_new[s.name]) for s in terms], judged


def _pin_down(parts: list[tuple[Frame, str]], model: AugmentedFEE, fit, named, form_report: dict | None,
              alpha: float) -> dict:
    """Each named term's rivals among the library's forms (``forms.rival_forms``) on each of
    ``parts`` ((episodes, what they are)), θ ``fit`` for the named set, the one that claims least
    (``forms.weaker_pin``): {name: pin}. A discovered form its data do not pin down is named as such
    in its report entry, never as a mechanism."""
    pins = {}
    for s in named:
        each = [{**rival_forms(part, model, fit, s.name, alpha=alpha), "part": what} for part, what in parts]
        pins[s.name] = {**weaker_pin(*each), "judged_on": [p["part"] for p in each if pin_kind(p) != "unknown"],
                        "too_few": [{"part": p["part"], "why": p["why"]} for p in each
                                    if pin_kind(p) == "unknown" and len(each) > 1]}
    for d in (form_report or {}).get("discovered") or []:
        pin = pins.get(d["name"]) if d.get("confirmed", True) else None  # (no held-out part: never judged there)
        if pin is None:
            continue
        d["pin"] = pin
        kind = pin_kind(pin)
        if kind not in ("pinned", "unknown"):
            what = {"value": "characteristic value", "scale": "scale", "factor": "factor", "levels": "factor"}.get(kind, "form")
            # a form not pinned down is no evidence of a catalogue mechanism "in another form" either
            base = d["proposed_name"] if kind in ("value", "scale") else term_forms.proposed_name(d["name"])
            d["proposed_name"] = f"{base} (its {what} not pinned down by these data)"
    return pins


def _term_row(s, **extra) -> dict:
    """A named or tentative term for the report: its score, the simulator plugin that switches it on, ``extra``."""
    return {**s.to_dict(), "plugin": plugin_spec(s.name, s.k), **extra}


def _mark_confirmed(form_report: dict | None, kept) -> None:
    """Each discovered form of the report is confirmed iff it is among ``kept`` (then with its k)."""
    k_of = {s.name: s.k for s in kept}
    for d in (form_report or {}).get("discovered") or []:
        d["confirmed"] = d["name"] in k_of
        if d["confirmed"]:
            d["k"] = k_of[d["name"]]


