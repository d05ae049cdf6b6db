"""``soil_discrepancy BAG_DIR --out DIR``: where do the simulation model and measured episodes disagree?

Fits the FEE (plus any --accepted terms) to every episode's measured force, tests the residuals
by regime at the episode level, cross-validates each named candidate effect of
``soil_physics.force_terms`` across soil groups, adds the winner(s) to the model and shows the
force error before/after on held-out episodes. Writes discrepancy.md, discrepancy.json and PNGs;
prints the verdict. Exit 0 on success, 2 on bad input (the message names the problem), 1 if a
worker process died, 130 / 143 on Ctrl-C / SIGTERM (one line; the workers stopped).

    soil_discrepancy bags/disc/soil_inertia --out out/disc/soil_inertia
    soil_discrepancy bags/real --out out/disc/real --group-by episode --terms soil_inertia,rate_strength
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from soil_msgs_py.interrupts import said_interrupted, terminate_as_interrupt
from soil_msgs_py.process_pool import WorkerDied
from soil_msgs_py import cli_numbers
from soil_msgs_py.cli_paths import input_path, output_dir, refuse_directories, written_since


def parse_args(argv=None) -> argparse.Namespace:
    from pinn_estimator.dataset import add_skip_bad_bags_option

    from .candidates import FOLDS, HOLDOUT_SHARE, MIN_GAIN
    from .frame import DEFAULT_STRIDE, GROUP_BY
    from .regimes import ALPHA
    from .soil_tests import WIDTH_SIGMA

    p = argparse.ArgumentParser(prog="soil_discrepancy", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("bag_dir", type=input_path, help="directory of episode bags (rosbag2), simulated or measured")
    p.add_argument("--out", type=output_dir, required=True, help="output directory for discrepancy.md/.json and PNGs")
    p.add_argument("--terms", default=None, help="candidate terms, comma-separated (default: the whole catalogue)")
    p.add_argument("--accepted", default="", help="terms already in the model with fixed k, e.g. 'soil_inertia=4.0,...'")
    p.add_argument("--holdout", type=float, default=HOLDOUT_SHARE,
                   help="share of soil groups held out for the test, in (0, 1) (default %(default)s)")
    p.add_argument("--folds", type=int, default=FOLDS, help="cross-validation folds over soil groups (default %(default)s)")
    p.add_argument("--seed", type=cli_numbers.seed, default=0, help="seed of the held-out split and folds (default 0)")
    p.add_argument("--stride", type=int, default=DEFAULT_STRIDE, help="use every n-th tick in the soil, 1-60 (default %(default)s; every tick where "
                   "the force varies within n ticks, beyond noise, by 2 %% of |F|: a vibration n would fold)")
    p.add_argument("--alpha", type=float, default=ALPHA, help="significance level, Holm-corrected (default %(default)s)")
    p.add_argument("--min-gain", type=float, default=MIN_GAIN,
                   help="least share of held-out error a term must remove (default %(default)s)")
    p.add_argument("--group-by", choices=GROUP_BY, default="auto",
                   help="θ shared by episodes of the same metadata soil + I_d (auto; bags without a soil label beside labelled "
                        "ones: by γ; bags without any soil label: by γ as below when that makes >= 3 groups, else per "
                        "episode), one θ per episode, or shared by "
                        "episodes of the same measured unit weight γ (gamma: no label read)")
    p.add_argument("--allow-negative-k", action="store_true",
                   help="let a term's k take the sign opposite to its physics (default: k >= 0)")
    p.add_argument("--workers", type=cli_numbers.workers, default=None, help="processes for the cross-validation and the PINN retraining (default and 0: one per core)")
    p.add_argument("--no-cache", action="store_true", help="do not read/write the dataset cache in the bag directory")
    add_skip_bad_bags_option(p)
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--catalogue", type=Path, default=None, metavar="YAML",
                   help="your own catalogue of terms, tested beside the built-in one (e.g. an earlier run's "
                        "discovered_terms.yaml: terms: [{term: form:<scale>*<factor>, name: ..., k: ...}])")
    p.add_argument("--soil-tests", type=Path, default=None, metavar="YAML",
                   help="the soils' φ, c (and δ) measured apart from the machine (shear box, triaxial), per soil label: "
                        f"θ then moves only within each test's interval (± {WIDTH_SIGMA:g} std), so an effect θ would absorb shows "
                        "(soil_tests: [{soil, relative_density_pct?, phi_deg, phi_std_deg, c_kpa, c_std_kpa, "
                        "delta_deg?, delta_std_deg?}])")
    p.add_argument("--no-forms", action="store_true",
                   help="do not use the library of forms: no search when no catalogue term explains the residual, "
                        "and no check of a named term against the forms in its place")
    p.add_argument("--pinn-epochs", type=int, default=0,
                   help="also retrain the PINN without and with the named effect for this many epochs on the "
                        "selection episodes and compare them on the held-out ones (default 0: skip)")
    p.add_argument("--pinn-seeds", type=int, default=1,
                   help="PINNs per physics for that comparison, scored as an ensemble (default 1)")
    p.add_argument("--hidden", default=None, metavar="NAME=K[,NAME=K]|none",
                   help="for test data only: the effect(s) hidden in the simulator; the report says whether the "
                        "workflow named one of them first and which it found (the analysis never sees this)")
    p.add_argument("--quiet", action="store_true", help="print only the verdict")
    return p.parse_args(argv)


def main(argv=None) -> int:
    """The command line; Ctrl-C or SIGTERM (a scheduler's, timeout's) anywhere in the run is said in
    one line with what was written, exit 130 / 143 (no traceback). Anywhere: the run's own imports
    (torch for the PINNs) take seconds, and a stop there had been a traceback or a silent death."""
    args = parse_args(argv)
    started = time.time()
    try:
        with terminate_as_interrupt():
            return _run(args)
    except KeyboardInterrupt as exc:
        from .report import OUTPUT_FILES

        written = [name for name in OUTPUT_FILES if written_since(args.out / name, started)]
        return said_interrupted("soil_discrepancy", exc, f"the report in {args.out} is incomplete (written before the "
                                f"stop: {', '.join(written)}): run again for all of it" if written else "no report written")


def _run(args) -> int:
    from soil_physics.force_terms import parse_terms, refuse_repeats

    from .forms import load_catalogue
    from .soil_tests import load_soil_tests
    from .workflow import run_discrepancy
    from .report import OUTPUT_FILES, headline_verdict

    log = None if args.quiet else (lambda msg: print(msg, flush=True))
    if args.pinn_epochs < 0 or args.pinn_seeds < 1:
        bad = f"--pinn-epochs {args.pinn_epochs} must be >= 0" if args.pinn_epochs < 0 else f"--pinn-seeds {args.pinn_seeds} must be >= 1"
        print(f"soil_discrepancy: error: {bad}", file=sys.stderr)
        return 2
    if args.pinn_epochs and args.seed + args.pinn_seeds - 1 > cli_numbers.MAX_NUMPY_SEED:  # the PINNs' seeds, checked now
        print(f"soil_discrepancy: error: --seed {args.seed} with --pinn-seeds {args.pinn_seeds} seeds PINNs beyond "
              "2**32 - 1", file=sys.stderr)
        return 2
    predictors = {"PINN": _pinn_predictor(args.pinn_epochs, log, args.pinn_seeds)} if args.pinn_epochs else None
    try:
        accepted = parse_terms([s for s in args.accepted.split(",") if s.strip()])
        refuse_repeats(accepted, "--accepted")
        for name, k in accepted:
            if k < 0 and not args.allow_negative_k:  # candidates are held to k >= 0 for the same reason
                print(f"soil_discrepancy: warning: --accepted {name}={k:g}: a negative k turns the term against its "
                      "mechanism; the search will name terms that undo it (candidates are held to k >= 0 unless "
                      "--allow-negative-k)", file=sys.stderr)
        refuse_directories([args.out / name for name in OUTPUT_FILES])
        hidden = None if args.hidden in (None, "none") else parse_terms([t for t in args.hidden.split(",") if t.strip()])
        if hidden is not None:
            if not hidden:  # (it failed in hidden_check, after the whole run)
                raise ValueError(f"--hidden {args.hidden!r} names no term: give NAME=K[,NAME=K], or none for a control")
            refuse_repeats(hidden, "--hidden")
        user_terms = {t["term"]: t["name"] for t in load_catalogue(args.catalogue)} if args.catalogue else {}
        soil_tests = load_soil_tests(args.soil_tests) if args.soil_tests else ()
        report = run_discrepancy(
            args.bag_dir, args.out, predictors=predictors, terms=args.terms, accepted=accepted, holdout=args.holdout, folds=args.folds,
            seed=args.seed, stride=args.stride, alpha=args.alpha, min_gain=args.min_gain, group_by=args.group_by,
            allow_negative_k=args.allow_negative_k, workers=args.workers, cache=not args.no_cache,
            skip_bad_bags=args.skip_bad_bags, plots=not args.no_plots, forms=not args.no_forms, user_terms=user_terms,
            soil_tests=soil_tests, log=log,
        )
    except (ValueError, FileNotFoundError, NotADirectoryError) as exc:
        print(f"soil_discrepancy: error: {exc}", file=sys.stderr)
        return 2
    except WorkerDied as exc:  # a run that broke, not the input
        print(f"soil_discrepancy: error: {exc}", file=sys.stderr)
        return 1
    headline = headline_verdict(report)  # the class, as the report's headline says it ("partly explained", ...)
    summary = report["summary"]
    print(f"verdict: {summary}" if not headline or summary.startswith(report.get("verdict", "")) else
          f"verdict: {headline} — {summary}")
    if args.hidden is not None:
        check = hidden_check(report, hidden)
        print(f"hidden effect: {check['text']}")
        _append_check(args.out, check)
    for spec in report["model"]["plugin_specs"]:
        print(f"re-simulate with: --plugin \"{spec}\"")
    if not args.quiet:
        print(f"({report['run_time_s']:.1f} s; report in {args.out / 'discrepancy.md'})")
    return 0


def _pinn_predictor(epochs: int, log, seeds: int = 1):
    """The workflow's predictor hook: retrain the PINN without/with the named terms (pinn_check)."""
    from .pinn_check import pinn_gap

    def run(test_frame, model_before, model_after, context):
        if model_after == model_before:
            return {"skipped": "no effect was named, so there is nothing to retrain the PINN with"}
        if context.get("dataset") is None:
            raise ValueError("the PINN comparison needs the episodes' Dataset (run on a bag directory or pass dataset=)")
        return pinn_gap(context["dataset"], test_frame, context["selection_episodes"], model_before, model_after,
                        epochs=epochs, seed=context["seed"], seeds=seeds, edges=context.get("edges"),
                        workers=context.get("workers", 1), log=log)

    return run


_DEFAULT_WORLD_OWN = (" (the default world has effects of its own that the model lacks, soil_sim_node/effects.py: "
                      "what is named before or instead of the hidden effect may be one of them)")


def hidden_check(report: dict, hidden) -> dict:
    """Did the workflow name the effect hidden in the test data (or none, for a control)? ``hidden``:
    None, or (name, k) pairs. With several hidden at once the answer is correct when the first term
    named is one of them (the dominant one, as a rule) and every hidden one is said found or not."""
    named = [a["name"] for a in report["selection"]["accepted"]]
    k = {a["name"]: a.get("k") for a in report["selection"]["accepted"]}
    idle = _never_acted(report)
    if hidden is not None and all(name in idle for name, _ in hidden):
        # a plugin that can never act here (surcharge_drag where no pile stands before the blade, Q = 0 in
        # the fee world) hides nothing: "missed" blamed the workflow for an effect the data do not hold
        hidden = [tuple(h) for h in hidden]
        ok = not named
        said = ", ".join(f"{name} (k = {k_hidden:g})" for name, k_hidden in hidden)
        answer = (": correct" if ok else _DEFAULT_WORLD_OWN if (report.get("data") or {}).get("world") == "default"
                  else ": WRONG")
        text = (f"{said} hidden, but {'it' if len(hidden) == 1 else 'none of them'} never acted on these data (its "
                "basis, and so its force, is 0 on every analysed tick the workflow tested it on: e.g. surcharge_drag "
                "where no pile stands before the blade, Q = 0, as in the fee world), so the data are a control; named "
                f"{named or 'none'}{answer}")
    elif hidden is None:
        ok = not named
        text = "none hidden; " + ("none named: correct" if ok else f"named {named}: WRONG")
    else:
        hidden = [tuple(h) for h in hidden]
        ok = bool(named) and named[0] in {name for name, _ in hidden}
        # a first term named whose own column on these data a hidden one is (its rival check lists it as the
        # same statement: w d tanh(v_x / 1 m/s) on two speeds is rate strength's w d v_x) is that effect here
        same = next((name for name, _ in hidden if named and _own_column(report, named[0], name)), None)
        if ok:
            answer = ": correct"
        elif same:
            ok = True
            answer = (f": correct, {named[0]} being {same}'s own column on these data (the same statement: its rival "
                      "check lists it so); which of the two is the mechanism these data cannot tell")
        elif (report.get("data") or {}).get("world") == "default":
            # the default world has effects of its own the model lacks (soil_sim_node/effects.py): what is named
            # first there may be one of them, so "wrong" says too much; whether the hidden one was named says enough
            anywhere = [name for name, _ in hidden if name in named]
            answer = (f": {', '.join(anywhere)} named, not first" if anywhere else ": not named") + _DEFAULT_WORLD_OWN
        elif not named:  # an honest miss (unexplained, or no discrepancy), not a confident wrong name
            answer = ": missed (nothing named)"
        else:
            answer = ": WRONG"
        if len(hidden) == 1:
            (name, k_hidden), = hidden
            text = (f"{name} (k = {k_hidden:g}) hidden; named {named or 'none'}"
                    + (f" with k = {k[name]:.4g}" if name in k else "") + answer)
        else:
            found = "; ".join(f"{name} (k = {k_hidden:g}) hidden" + (f", named with k = {k[name]:.4g}" if name in k
                                                                    else ", never acted on these data" if name in idle
                                                                    else ", not named") for name, k_hidden in hidden)
            text = f"{found}; named {named or 'none'}" + answer
    test = report.get("test") or {}
    before, after = (test.get("before") or {}).get("rmse"), (test.get("after") or {}).get("rmse")
    ratio = after / before if before and after is not None else None
    return {"hidden": None if hidden is None else list(hidden[0]),
            "hidden_all": None if hidden is None else [list(h) for h in hidden], "named": named, "correct": ok,
            "heldout_rmse_before_n": before, "heldout_rmse_after_n": after,
            "heldout_error_ratio": ratio, "text": text + (f"; held-out RMSE × {ratio:.2f}" if ratio else "")}


def _own_column(report: dict, name: str, form: str) -> bool:
    """Whether the named term ``name``'s rival check found ``form`` to be its own column on these
    data, whatever the sign either is written with, of the forms the report lists (at most
    ``forms.RIVALS_SHOWN``: a form beyond them is not found here)."""
    from .forms import _unsigned

    term = next((a for a in report["selection"]["accepted"] if a["name"] == name), {})
    return _unsigned(form) in {_unsigned(n) for n in (term.get("pin") or {}).get("same_column") or []}


def _never_acted(report: dict) -> set[str]:
    """The candidate terms the workflow found with a basis of 0 on every analysed tick it tested them
    on (its first round's scores carry ``ZERO_BASIS_NOTE``): they act nowhere in these data."""
    rounds = (report.get("selection") or {}).get("rounds") or []
    scores = rounds[0].get("scores", []) if rounds else []
    from .candidates import ZERO_BASIS_NOTE

    return {s["name"] for s in scores if s.get("note") == ZERO_BASIS_NOTE}


def _append_check(out: Path, check: dict) -> None:
    import json

    from soil_msgs_py import strict_json

    from .report import REPORT_JSON, REPORT_MD

    md, js = out / REPORT_MD, out / REPORT_JSON
    if md.exists():
        md.write_text(md.read_text() + "\n## Check against the hidden effect (test data only)\n\n" + check["text"] + "\n")
    if js.exists():
        data = json.loads(js.read_text())
        data["hidden_check"] = check
        js.write_text(strict_json.dumps(data, indent=1))


if __name__ == "__main__":
    sys.exit(main())
