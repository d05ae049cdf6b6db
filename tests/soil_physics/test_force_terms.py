"""The catalogue of candidate effects (soil_physics.force_terms): one implementation for the
simulator (as an effect plugin), the FEE model and the PINN (NumPy and torch)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from soil_physics import force_terms as X
from soil_physics.force_inputs import ForceInputs
from soil_msgs_py.params import DEG, GRAVITY_M_S2
from soil_sim_node.effects import PluginError, load_plugins
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig
from soil_sim_node.effects import effects_for_mode


def inputs(**over):
    base = dict(d=np.array([0.2, 0.1, -0.05]), q=np.array([3e3, 1e3, 0.0]), v_x=np.array([0.5, 1.0, 0.5]),
                v_z=np.array([0.0, -0.1, 0.0]), gamma=18e3, w=3.164, rho=80 * DEG, alpha=0.0, phi=30 * DEG,
                c=2e3, delta=15 * DEG, distance_in_soil=np.array([2.0, 0.5, 0.0]),
                f_fee_x=np.array([1e4, 5e3, 0.0]), f_fee_z=np.array([-2e3, 1e3, 0.0]))
    return ForceInputs(**{**base, **over})


@pytest.mark.parametrize("name", sorted(X.CATALOGUE))
def test_every_term_is_documented_zero_out_of_soil_and_same_in_torch(name):
    term = X.CATALOGUE[name]
    assert term.formula and term.k_unit and term.physics and term.title and term.k_nominal > 0
    bx, bz = term.basis(inputs())
    assert np.isfinite(bx).all() and np.isfinite(bz).all()
    assert bx[2] == 0.0 and bz[2] == 0.0, "no soil, no force"
    assert abs(bx[0]) + abs(bz[0]) > 0, "a blade 0.2 m deep feels every effect"
    # the axes it says it acts on are those its basis has a part on (a report blames an axis's part by them)
    assert term.axes == "x" * bool(np.any(bx[:2])) + "z" * bool(np.any(bz[:2])), (term.axes, bx, bz)
    t = {k: (torch.tensor(v, dtype=torch.float64) if isinstance(v, np.ndarray) else v) for k, v in inputs().__dict__.items()}
    tx, tz = term.basis(ForceInputs(**t))
    np.testing.assert_allclose(tx.numpy(), bx, rtol=1e-12)
    np.testing.assert_allclose(tz.numpy(), bz, rtol=1e-12)


def test_soil_inertia_is_the_momentum_flux_by_hand():
    bx, bz = X.CATALOGUE["soil_inertia"].basis(inputs())
    assert bx[0] == pytest.approx(18e3 / GRAVITY_M_S2 * 3.164 * 0.2 * 0.25) and bz[0] == 0.0
    assert bx[1] / bx[0] == pytest.approx((0.1 * 1.0) / (0.2 * 0.25)), "∝ d v_x²"


def test_apply_sums_k_times_basis_and_parse_names_bad_specs():
    terms = X.parse_terms(["soil_inertia=2", ("rate_strength", "5e3")])
    assert terms == (("soil_inertia", 2.0), ("rate_strength", 5000.0))
    fx, fz = X.apply(terms, inputs())
    bx1, _ = X.CATALOGUE["soil_inertia"].basis(inputs())
    bx2, _ = X.CATALOGUE["rate_strength"].basis(inputs())
    np.testing.assert_allclose(fx, 2 * bx1 + 5e3 * bx2)
    for bad, needle in (("nope=1", "not one of"), ("soil_inertia", "name=k"), ("soil_inertia=x", "not a number"),
                        ("soil_inertia=inf", "finite")):
        with pytest.raises(ValueError, match=needle):
            X.parse_terms([bad])
    # a form's wrong part is named (both were listed as if both were wrong)
    from soil_physics import term_forms

    for bad, needle in (("form:gd2w_x*sat7", "factor 'sat7' is not one of .* \\(scale 'gd2w_x' is known\\)"),
                        ("form:foo_x*sat6", "scale 'foo_x' is not one of [^;]*$"),
                        ("form:foo_x*bar", "scale 'foo_x' is not one of .*; nor is factor 'bar'"),
                        ("form:gd2w_x", "no '\\*'")):
        with pytest.raises(ValueError, match=needle):
            term_forms.parse(bad)


def test_a_huge_integer_k_is_refused_naming_the_term():
    """A (name, k) pair from JSON or YAML may hold a 400-digit integer: float() overflowed (a
    traceback); now it is not finite, named with the term and k cut short."""
    with pytest.raises(ValueError, match=r"effect term soil_inertia: k=1000.*\.\.\. \(\d+ characters\) must be finite"):
        X.parse_terms([("soil_inertia", 10**400)])


def test_simulator_switches_the_same_term_on_as_a_plugin():
    """'soil_physics.force_terms:plugin term=... k=...' fits in a CLI flag or a ROS string parameter."""
    (plugin,) = load_plugins(["soil_physics.force_terms:plugin term=rate_strength k=8000"])
    assert plugin.params == {"term": "rate_strength", "k": 8000.0}
    with pytest.raises(PluginError, match="key=value"):
        load_plugins(["soil_physics.force_terms:plugin rate_strength"])
    spec = EpisodeSpec("Loam", 40.0, 0.5, 0.2, seed=3, duration_s=3.0)
    plain = run_episodes(SimConfig(world_mode="fee", effects=effects_for_mode("fee")), [spec])[0]
    extra = run_episodes(SimConfig(world_mode="fee", effects=effects_for_mode("fee"),
                                   plugins=("soil_physics.force_terms:plugin term=rate_strength k=8000",)), [spec])[0]
    late = slice(120, None)
    added = extra.forces[late, 0].mean() - plain.forces[late, 0].mean()
    expected = 8000 * (3.164 * extra.column("d")[late] * np.maximum(extra.column("v_x")[late], 0)).mean()
    assert added == pytest.approx(expected, rel=0.35), "the measured force carries the switched-on term"
    assert math.isfinite(added) and added > 0


def test_a_friction_term_beyond_tan_phi_is_called_implausible_and_other_terms_have_no_bound():
    """A Coulomb friction coefficient is at most tan φ, Table 1's soils reach φ 45°: a base friction
    or a pushed pile fitted with k > 1 is no friction (two effects hidden at once gave base friction
    k 2.29 beside them). Terms without a physical bound, and library forms, are never called so."""
    assert X.FRICTION_K_MAX == pytest.approx(1.0)
    for name in ("base_friction", "surcharge_drag"):
        assert X.implausible_k(name, 0.99) == "" and X.implausible_k(name, 0.0) == ""
        words = X.implausible_k(name, 2.29)
        assert words.startswith("k = 2.29 is beyond what") and "tan 45° = 1.00" in words, words
    assert X.implausible_k("soil_inertia", 40.0) == "" and X.implausible_k("rate_strength", 1e6) == ""
    assert X.implausible_k("form:wd_x*vx", 1e6) == ""
