"""The PINN retrained with augmented physics: F̂ = F_FEE + Σ k·B + F_r.

Catalogue terms (``soil_physics.force_terms``) with fixed k are part of the model config, so
a checkpoint carries them; without terms the model is the paper's PINN, bit for bit.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from pinn_estimator import checkpoint as ck
from pinn_estimator.dataset import load_dataset
from soil_physics.travel import distance_in_soil, soil_advance, soil_time_step, time_in_soil
from pinn_estimator.inference import WindowTensors, predict
from pinn_estimator.loss import pinn_loss
from pinn_estimator.model import DISTANCE_TERMS, RESIDUAL_FORCE_FRACTION, EstimatorNet, ModelConfig
from pinn_estimator.train import TrainConfig, main as train_main, train
from soil_physics import force_terms as X
from soil_physics.force_inputs import ForceInputs
from soil_physics import fee
from soil_msgs_py.params import KNOWN_PARAMS, TABLE1, UNKNOWN_PARAMS

SAMPLES = Path(__file__).resolve().parents[2] / "bags" / "samples"
SMALL = dict(d_model=16, n_heads=2, n_layers=1, ff_dim=32)
SMALL_CLI = ["--d-model", "16", "--n-heads", "2", "--n-layers", "1", "--ff-dim", "32"]
ALL_NOMINAL = tuple((name, term.k_nominal) for name, term in X.CATALOGUE.items())


@pytest.fixture(scope="module")
def samples():
    return load_dataset(SAMPLES, cache=False)


def _windows(ds, ends):
    ends = torch.as_tensor(ends, dtype=torch.int64)
    obs, known, force = WindowTensors(ds).batch(ends)
    return obs, known, force, torch.as_tensor(ds.distance_in_soil(), dtype=torch.float32)[ends]


def _model(ds, terms=(), seed=0):
    torch.manual_seed(seed)
    return EstimatorNet(ModelConfig(**SMALL, extra_terms=terms), ds.observations.mean(0), ds.observations.std(0) + 1e-9)


def _term_inputs(out, known, distance) -> ForceInputs:
    """The ForceInputs the model must use, rebuilt from a model output: Θ_k, the clipped Θ_u,
    d' = d + Δd clipped like the FEE call, the travel in soil and the model's own F_FEE."""
    k = {n: known[:, j] for j, n in enumerate(KNOWN_PARAMS)}
    th = out["theta"]
    d_prime = torch.clamp(k["d"] + th[:, 4], *TABLE1["d"].limits)
    return ForceInputs(
        d=d_prime, q=k["q"], v_x=k["v_x"], v_z=k["v_z"], gamma=k["gamma"], w=k["w"], rho=k["rho"], alpha=k["alpha"],
        phi=th[:, 0], c=th[:, 1], delta=th[:, 2], distance_in_soil=distance,
        f_fee_x=out["force_fee"][:, 0], f_fee_z=out["force_fee"][:, 1],
    )


# ------------------------------------------------------------------------------ config
def test_config_validates_and_round_trips_through_a_checkpoint(samples, tmp_path):
    cfg = ModelConfig(**SMALL, extra_terms=["soil_inertia=2", ("compaction_hardening", "0.05")])
    assert cfg.extra_terms == (("soil_inertia", 2.0), ("compaction_hardening", 0.05)) and cfg.needs_distance
    assert not ModelConfig(extra_terms=(("soil_inertia", 2.0),)).needs_distance
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    model = EstimatorNet(cfg, samples.observations.mean(0), samples.observations.std(0) + 1e-9)
    path = ck.save_checkpoint(tmp_path / "x.pt", model, train_config={}, dataset={}, split={}, metrics={}, history={})
    raw = torch.load(path, weights_only=True)  # plain containers: no code runs to read it
    assert raw["model_config"]["extra_terms"] == [["soil_inertia", 2.0], ["compaction_hardening", 0.05]]
    loaded, _ = ck.load_model(path)
    assert loaded.cfg == cfg
    obs, known, _, dist = _windows(samples, [100, 900, 1700])
    model.eval()
    with torch.no_grad():
        a, b = model(obs, known, dist), loaded(obs, known, dist)
    assert all(torch.equal(a[key], b[key]) for key in a)
    # a checkpoint written before extra terms existed has no key and loads as the paper's PINN
    old = torch.load(ck.DEFAULT_CHECKPOINT, weights_only=True)
    assert "extra_terms" not in old["model_config"]
    assert ck.load_model(ck.DEFAULT_CHECKPOINT)[0].cfg.extra_terms == ()


@pytest.mark.parametrize("terms, match", [
    ((("no_such_effect", 1.0),), "no_such_effect"),
    ((("soil_inertia", "fast"),), "soil_inertia: k='fast' is not a number"),
    ((("soil_inertia", math.inf),), "soil_inertia: k=inf must be finite"),
    (("soil_inertia",), "soil_inertia.*must look like 'name=k'"),
    ((("soil_inertia", 1.0), ("soil_inertia", 2.0)), "soil_inertia is given more than once"),
    ("soil_inertia=2", "not one string"),
])
def test_bad_extra_terms_are_named(terms, match):
    with pytest.raises(ValueError, match=match):
        ModelConfig(extra_terms=terms)


def test_physics_free_model_takes_no_extra_terms():
    with pytest.raises(ValueError, match="soil_inertia.*need kind='pinn'"):
        ModelConfig(kind="physics_free", extra_terms=(("soil_inertia", 1.0),))


# ------------------------------------------------------------------------------ forward
def test_shipped_model_is_unchanged_without_terms(samples):
    """pinn_default.pt: the same numbers as before extra terms existed, and F̂ = F_FEE + F_r in
    the original arithmetic (bit for bit), whatever distance is passed."""
    model, _ = ck.load_model(ck.DEFAULT_CHECKPOINT)
    obs, known, _, dist = _windows(samples, [59, 700, 1500])
    with torch.no_grad():
        out = model(obs, known)
        again = model(obs, known, dist)
        # the paper's PINN, rebuilt from the model's parts (model.py without extra terms)
        head = model.head(model.backbone(obs, known))
        n = len(UNKNOWN_PARAMS)
        theta = torch.maximum(torch.minimum(head[:, :n] * model.theta_span + model.theta_lo, model.limit_hi), model.limit_lo)
        residual = head[:, n:] * (RESIDUAL_FORCE_FRACTION * model.force_scale)
        k = {name: known[:, j] for j, name in enumerate(KNOWN_PARAMS)}
        d_prime = torch.clamp(k["d"] + theta[:, 4], *TABLE1["d"].limits)
        fx, fz, _ = fee.fee_xz({**k, "phi": theta[:, 0], "c": theta[:, 1], "delta": theta[:, 2], "d": d_prime}, beta=theta[:, 3])
    assert torch.equal(out["force"], torch.stack([fx, fz], 1) + residual)
    assert torch.equal(out["force"], out["force_fee"] + out["force_residual"])
    assert torch.equal(out["force_extra"], torch.zeros(3, 2))
    assert all(torch.equal(out[key], again[key]) for key in out)
    # values recorded from the pre-issue-6 model.py on these windows (tolerance: CPU kernels)
    expected_force = [[22660.607, -16102.265], [18638.229, -12335.659], [9552.122, -801.786]]
    expected_theta = [[0.68169725, 1333.3121, 0.67468768, 0.20229183, -0.02154251],
                      [0.61824715, 0.0, 0.61909628, 0.22957726, -0.04935720],
                      [0.31688580, 3279.2905, 0.25966957, 0.49901113, -0.00070010]]
    assert np.allclose(out["force"].numpy(), expected_force, rtol=1e-4, atol=0.5)
    assert np.allclose(out["theta"].numpy(), expected_theta, rtol=1e-4, atol=1e-4)


def test_extra_force_is_sum_of_k_times_basis_on_the_models_own_inputs(samples):
    model = _model(samples, ALL_NOMINAL)
    ends = samples.window_ends(range(len(samples)), 9)
    obs, known, force, dist = _windows(samples, ends)
    out = model(obs, known, dist)
    with torch.no_grad():
        ex, ez = X.apply(ALL_NOMINAL, _term_inputs(out, known, dist))
    direct = torch.stack([ex, ez], 1)
    assert torch.isfinite(direct).all() and direct.abs().sum() > 0
    assert torch.allclose(out["force_extra"], direct, rtol=1e-6, atol=1e-3)
    assert torch.allclose(out["force"] - out["force_fee"] - out["force_residual"], direct, rtol=1e-5, atol=2e-2)
    # each term is there with its own k (soil inertia alone: x only, k (γ/g) w d' v_x²)
    alone = _model(samples, (("soil_inertia", 2.0),))(obs, known)
    k = {n: known[:, j] for j, n in enumerate(KNOWN_PARAMS)}
    d_prime = torch.clamp(k["d"] + alone["theta"][:, 4], *TABLE1["d"].limits)
    by_hand = 2.0 * k["gamma"] / 9.81 * k["w"] * d_prime * k["v_x"].clamp(min=0) ** 2
    assert torch.allclose(alone["force_extra"][:, 0], by_hand, rtol=2e-3) and torch.all(alone["force_extra"][:, 1] == 0)
    # the loss trains through the augmented physics with finite gradients
    loss, _ = pinn_loss(out, force, known)
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_singular_terms_at_the_limits_of_phi_give_zero_not_nan(samples):
    """tip_penetration is 0/0 at φ = 0 and side_wall_shear's gradient is NaN at φ = 90°: the
    model counts such samples' term as 0 and keeps every gradient finite."""
    obs, known, force, dist = _windows(samples, samples.window_ends(range(len(samples)), 20))
    for bias in (-5.0, 5.0):  # φ far below 0 / above 90° before clipping
        model = _model(samples, (("tip_penetration", 1.0), ("side_wall_shear", 1.0)))
        with torch.no_grad():
            model.head.bias[0] = bias
        out = model(obs, known, dist)
        assert all(torch.isfinite(v).all() for v in out.values())
        pinn_loss(out, force, known)[0].backward()
        assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_distance_is_required_by_the_terms_that_use_it_only(samples):
    obs, known, _, dist = _windows(samples, [300, 1000, 1750])
    model = _model(samples, (("compaction_hardening", 0.05),)).eval()
    with pytest.raises(ValueError, match=r"\['compaction_hardening'\] need the blade's travel in soil"):
        model(obs, known)
    with pytest.raises(ValueError, match="distance has 2 values for a batch of 3"):
        model(obs, known, dist[:2])
    with torch.inference_mode():  # what the online estimator runs under
        near, far = model(obs, known, torch.zeros(3)), model(obs, known, dist)
    assert torch.equal(near["force_extra"], torch.zeros(3, 2))
    assert torch.allclose(far["force_extra"], 0.05 * dist[:, None] * far["force_fee"], rtol=1e-5, atol=1e-3)
    # no other catalogue term looks at distance_in_soil (else DISTANCE_TERMS must name it)
    base = dict(d=np.array([0.1, 0.2, -0.01]), q=2e3, v_x=0.5, v_z=-0.05, gamma=17e3, w=3.0, rho=1.0, alpha=0.0,
                phi=0.6, c=2e3, delta=0.3, f_fee_x=9e3, f_fee_z=-4e3)
    for name, term in X.CATALOGUE.items():
        a = term.basis(ForceInputs(**base, distance_in_soil=np.zeros(3)))
        b = term.basis(ForceInputs(**base, distance_in_soil=np.full(3, 7.0)))
        assert (name in DISTANCE_TERMS) == (not np.allclose(a, b)), name


# ------------------------------------------------------------------------------ distance in soil
def test_distance_in_soil_counts_forward_travel_with_the_blade_in_soil(samples):
    v_x = np.array([0.6, -0.3, 0.6, 0.6, 0.3])
    d = np.array([0.1, 0.1, 0.0, 0.2, 0.2])
    assert np.allclose(distance_in_soil(v_x, d), np.array([0.6, 0.6, 0.6, 1.2, 1.5]) / 60)
    assert np.allclose(distance_in_soil(v_x, d, dt=0.5), [0.3, 0.3, 0.3, 0.6, 0.75])
    with pytest.raises(ValueError, match="1-D"):
        distance_in_soil(np.zeros((3, 2)), np.zeros((3, 2)))
    # a running sum of soil_advance (what an online estimator keeps) gives the same values
    running, acc = [], 0.0
    for vx_t, d_t in zip(v_x, d):
        acc += float(soil_advance(vx_t, d_t))
        running.append(acc)
    assert np.allclose(running, distance_in_soil(v_x, d))
    # per row of a dataset: restarts at every episode, never decreases within one
    dist = samples.distance_in_soil()
    vx_col, d_col = KNOWN_PARAMS.index("v_x"), KNOWN_PARAMS.index("d")
    for e in range(len(samples)):
        rows = samples.episode_rows(e)
        assert np.array_equal(dist[rows], distance_in_soil(samples.known[rows, vx_col], samples.known[rows, d_col]))
        assert dist[rows][0] < 0.01 and np.all(np.diff(dist[rows]) >= 0)
        assert 3.0 < dist[rows][-1] < 6.0  # 10 s at ~0.45 m/s, nearly all of it in soil


def test_time_in_soil_counts_the_ticks_with_the_blade_in_soil(samples):
    d = np.array([0.0, 0.1, 0.1, 0.0, 0.2])
    assert np.allclose(time_in_soil(d), np.array([0, 1, 2, 2, 3]) / 60)
    assert np.allclose(time_in_soil(d, dt=0.5), [0.0, 0.5, 1.0, 1.0, 1.5])
    with pytest.raises(ValueError, match="1-D"):
        time_in_soil(np.zeros((3, 2)))
    assert np.allclose(np.cumsum([float(soil_time_step(d_t)) for d_t in d]), time_in_soil(d))  # the running sum
    t, d_col = samples.time_in_soil(), KNOWN_PARAMS.index("d")
    for e in range(len(samples)):
        rows = samples.episode_rows(e)
        assert np.array_equal(t[rows], time_in_soil(samples.known[rows, d_col]))
        assert 9.0 < t[rows][-1] <= 10.0  # a 10 s episode, nearly all of it in soil


def test_time_in_soil_is_required_by_the_forms_that_use_it_only(samples):
    """A discovered form on time in soil (``form:feex*tau``: k F_FEE,x τ / 10 s) is a PINN extra
    term like a catalogue one: the model asks for each window's time in soil, by name."""
    ends = [300, 1000, 1750]
    obs, known, _, dist = _windows(samples, ends)
    t = torch.as_tensor(samples.time_in_soil(), dtype=torch.float32)[ends]
    model = _model(samples, (("form:feex*tau", 0.3),)).eval()
    assert model.needs_time and not model.needs_distance
    with pytest.raises(ValueError, match=r"\['form:feex\*tau'\] need the blade's time in soil"):
        model(obs, known, dist)
    with pytest.raises(ValueError, match="time_in_soil has 2 values for a batch of 3"):
        model(obs, known, dist, t[:2])
    with torch.inference_mode():
        out = model(obs, known, None, t)  # no distance term: the travel is not asked for
    assert torch.allclose(out["force_extra"][:, 0], 0.3 * out["force_fee"][:, 0] * t / 10.0, rtol=1e-5, atol=1e-3)
    assert torch.equal(out["force_extra"][:, 1], torch.zeros(3))
    assert not _model(samples, (("compaction_hardening", 0.05),)).needs_time


# ------------------------------------------------------------------------------ training
@pytest.fixture(scope="module")
def samples_split(samples, tmp_path_factory) -> Path:
    """A checkpoint carrying a 2/1 train/val split of bags/samples for --split-from: their three
    episodes are three different strata, too few for the trainer's own stratified split."""
    path = tmp_path_factory.mktemp("split") / "split.pt"
    split = {"train": sorted(samples.names[:2]), "val": [samples.names[2]], "test": []}
    return ck.save_checkpoint(path, _model(samples), train_config={}, dataset={}, split=split, metrics={}, history={})


def test_train_cli_with_an_extra_term_writes_a_checkpoint_that_carries_it(samples, samples_split, tmp_path):
    out = tmp_path / "aug.pt"
    args = ["--data", str(SAMPLES), "--out", str(out), "--split-from", str(samples_split), "--epochs", "2",
            "--stride", "20", "--eval-stride", "20", "--quiet", "--no-cache", "--threads", "1", *SMALL_CLI,
            "--extra-term", "soil_inertia=2"]
    assert train_main(args) == 0
    model, meta = ck.load_model(out)
    assert model.cfg.extra_terms == (("soil_inertia", 2.0),)
    assert meta["model_config"]["extra_terms"] == [["soil_inertia", 2.0]] and meta["metrics"]["epochs_run"] == 2
    ends = samples.window_ends(range(len(samples)), 25)
    got = predict(model, WindowTensors(samples), ends)  # soil_inertia needs no distance
    assert all(np.isfinite(v).all() for v in got.values())
    assert np.allclose(got["force"], got["force_fee"] + got["force_extra"] + got["force_residual"], rtol=1e-5, atol=0.05)
    assert np.all(got["force_extra"][:, 0] >= 0) and got["force_extra"][:, 0].max() > 50  # k (γ/g) w d v_x² [N]


def test_training_passes_distance_in_soil_for_compaction_hardening(samples, samples_split):
    """Training and validation batches carry each window's travel in soil (the model raises
    without it), and training with the term stays finite."""
    split = ck.read_checkpoint(samples_split)["split"]
    cfg = TrainConfig(epochs=1, stride=30, eval_stride=30, threads=1)
    model, _, history, _ = train(samples, cfg, ModelConfig(**SMALL, extra_terms=(("compaction_hardening", 0.05),)),
                                 split=split, progress=False, log=lambda *_: None)
    assert model.cfg.needs_distance and np.isfinite(history["val_loss"]).all()


def test_training_passes_time_in_soil_for_a_form_on_time(samples, samples_split):
    """Training, validation and prediction carry each window's time in soil for a form that looks
    at it (the model raises without it)."""
    split = ck.read_checkpoint(samples_split)["split"]
    cfg = TrainConfig(epochs=1, stride=30, eval_stride=30, threads=1)
    model, _, history, _ = train(samples, cfg, ModelConfig(**SMALL, extra_terms=(("form:feex*tau", 0.3),)),
                                 split=split, progress=False, log=lambda *_: None)
    assert model.cfg.needs_time and np.isfinite(history["val_loss"]).all()
    got = predict(model, WindowTensors(samples), samples.window_ends(range(len(samples)), 200))
    assert np.isfinite(got["force"]).all() and (got["force_extra"][:, 0] != 0).any()


@pytest.mark.parametrize("spec, named", [
    ("no_such_effect=1", "no_such_effect"),
    ("soil_inertia=fast", "soil_inertia"),
    ("soil_inertia", "soil_inertia"),
    ("rate_strength=nan", "rate_strength"),
])
def test_bad_extra_term_option_exits_2_naming_it(spec, named, tmp_path, capsys):
    out = tmp_path / "x.pt"
    assert train_main(["--data", str(SAMPLES), "--out", str(out), "--quiet", "--no-cache", "--extra-term", spec]) == 2
    err = capsys.readouterr().err
    assert "pinn_train: error" in err and named in err
    assert not out.exists()


def test_extra_term_option_on_the_physics_free_model_exits_2(tmp_path, capsys):
    args = ["--data", str(SAMPLES), "--out", str(tmp_path / "x.pt"), "--quiet", "--kind", "physics_free",
            "--extra-term", "soil_inertia=2"]
    assert train_main(args) == 2
    assert "need kind='pinn'" in capsys.readouterr().err
