"""Soil tests hold θ where the forces cannot: an effect θ would absorb is left in the residual.

An adhesion pulling the blade down in proportion to cohesion (tests/sim_plugins.adhesion_pull,
F_z = −0.5 c w d) has the profile of the FEE's own cohesion terms, so with θ fitted freely per
soil group the forces say nothing is missing and the soil estimates are wrong. With the soils'
φ, c, δ measured apart from the machine (here the simulator's own soils, ± 1°, 10 %, 1°), θ
may move only within those intervals and the effect shows.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from soil_discrepancy import build_frame, run_discrepancy
from soil_discrepancy.cli import main as cli_main
from soil_discrepancy.fee_fit import fit_fixed, residuals
from soil_discrepancy.forms import theta_jacobian
from soil_discrepancy.regimes import group_misfit
from soil_discrepancy.soil_tests import WIDTH_SIGMA, hold_theta, load_soil_tests, parse_soil_tests, unmatched
from soil_physics.augmented_fee import AugmentedFEE
from soil_physics.soils import CATALOGUE as SOILS
from soil_physics.soils import get_soil
from soil_sim_node.batch import grid_specs
from soil_sim_node.simulator import soil_tool_friction_rad

from .test_discrepancy import RUN, named_verdict, simulated

DENSITIES = (20.0, 80.0)
STRIDE = 4


def lab_results(densities=DENSITIES, phi_shift_deg: dict | None = None) -> dict:
    """The soil tests a lab would give for the simulator's soils (value at each I_d, σ 1°, 10 % + 0.2 kPa, 1°);
    ``phi_shift_deg``: {soil: shift} a wrong test of φ."""
    rows = []
    for name in SOILS:
        for i_d in densities:
            p = get_soil(name).at(i_d)
            c_kpa = p.c / 1e3
            rows.append({"soil": name, "relative_density_pct": i_d,
                         "phi_deg": math.degrees(p.phi) + (phi_shift_deg or {}).get(name, 0.0), "phi_std_deg": 1.0,
                         "c_kpa": c_kpa, "c_std_kpa": 0.1 * c_kpa + 0.2,
                         "delta_deg": math.degrees(soil_tool_friction_rad("fee")), "delta_std_deg": 1.0})
    return {"soil_tests": rows}


@pytest.fixture(scope="module")
def adhesion():
    """The adhesion's episodes, blind (simulated, as the soil tests' reading of bags is the CLI's)."""
    specs = grid_specs(list(SOILS), list(DENSITIES), [0.3, 1.0], [0.1, 0.25], 1, seed_base=0, duration_s=10.0)
    return simulated(specs, ("tests.sim_plugins:adhesion_pull k=0.5",))


def test_an_effect_theta_absorbs_shows_only_with_soil_tests(adhesion, tmp_path):
    ds = adhesion
    run = {**RUN, "stride": STRIDE}
    free = run_discrepancy(dataset=ds, out_dir=None, plots=False, **run)
    assert free["verdict"] == "no significant discrepancy", free["summary"]  # the forces alone: θ took it in
    held = run_discrepancy(dataset=ds, out_dir=tmp_path, plots=False, soil_tests=parse_soil_tests(lab_results()), **run)
    assert held["regimes"]["rms_n"]["z"] > 2.0 * free["regimes"]["rms_n"]["z"], (held["regimes"]["rms_n"], free["regimes"]["rms_n"])
    assert len(held["data"]["soil_tests"]) == 8
    # where the effect acts (the cohesive soils) the fit leans on the tests' bounds, and the report says so
    bound = {r["name"]: r["theta_at_bound"] for r in held["regimes"]["misfit"]["rows"] if r["kind"] == "group"}
    assert any("soil test" in b for g, hits in bound.items() if g.startswith(("Clay", "Loam")) for b in hits), bound
    assert not any(hits for g, hits in bound.items() if g.startswith(("Sand", "Gravel"))), bound
    # found with its form, −k c w d in z, and its k; naming it releases θ from the tests' bounds (the
    # dense clay's φ stays on its test's lower bound, as without the effect: the free fit takes 22.6° for 25°)
    assert held["selection"]["accepted"] and held["verdict"] == named_verdict(held), held["summary"]
    (named,) = held["selection"]["accepted"]
    assert named["name"] == "form:cwd_z*1" and 0.4 < named["k"] < 0.6, named
    after = [r["name"] for r in held["regimes_after"]["misfit"]["rows"] if r["kind"] == "group" and r["theta_at_bound"]]
    before = [g for g, hits in bound.items() if hits]
    assert len(after) < len(before) and set(after) <= {"Clay I_d=80%"}, (before, after)
    assert "STAND-IN" not in held["summary"], held["summary"]
    md = (tmp_path / "discrepancy.md").read_text()
    assert "Soil tests hold θ in 8 of 8 groups" in md and "| soil test: φ [°] / c [Pa] / δ [°] |" in md


def test_soil_tests_bound_theta_and_a_soil_they_rule_out_is_named(adhesion):
    frame = build_frame(adhesion, stride=8)
    # a wrong test: the clays' φ 6° too high; every other soil as it is
    held = hold_theta(frame, parse_soil_tests(lab_results(phi_shift_deg={"Clay": 6.0})))
    fit = fit_fixed(held, AugmentedFEE())
    for g, (lo, hi) in held.theta_boxes.items():
        theta = fit.theta[g]
        assert np.all(theta >= lo - 1e-9) and np.all(theta <= hi + 1e-9), (held.group_names[g], theta, lo, hi)
    r, _ = residuals(held, AugmentedFEE(), fit)
    rows = {r_["name"]: r_ for r_ in group_misfit(held, r, theta_table=fit.table(held))["rows"] if r_["kind"] == "group"}
    for name, row in rows.items():
        if name.startswith("Clay"):
            assert "φ at its soil test's lower bound" in row["theta_at_bound"], row
    # the held parameters' directions are not taken off the residual: their columns are zero
    J = theta_jacobian(held, AugmentedFEE(), fit)
    assert np.all(J == 0.0)
    assert np.any(theta_jacobian(frame, AugmentedFEE(), fit_fixed(frame, AugmentedFEE())) != 0.0)


def test_a_test_of_one_density_wins_and_tests_that_match_nothing_are_refused(adhesion):
    frame = build_frame(adhesion, stride=8)
    tests = parse_soil_tests({"soil_tests": [
        {"soil": "clay", "phi_deg": 20.0, "phi_std_deg": 1.0},  # every density, case-insensitive
        {"soil": "Clay", "relative_density_pct": 80, "phi_deg": 26.0, "phi_std_deg": 1.0, "c_kpa": 8.4, "c_std_kpa": 0.5}]})
    boxes = {frame.group_names[g]: b for g, b in hold_theta(frame, tests).theta_boxes.items()}
    assert sorted(boxes) == ["Clay I_d=20%", "Clay I_d=80%"]
    lo, hi = boxes["Clay I_d=80%"]
    assert math.degrees(lo[0]) == pytest.approx(26.0 - WIDTH_SIGMA) and lo[1] == pytest.approx(8.4e3 - WIDTH_SIGMA * 500)
    lo, hi = boxes["Clay I_d=20%"]
    assert math.degrees(hi[0]) == pytest.approx(20.0 + WIDTH_SIGMA) and np.isinf(lo[1]) and np.isinf(hi[2])  # c, δ free
    # a test no soil the FEE can fit with this blade lies in is refused when θ is fitted, naming group and range
    steep = hold_theta(frame, parse_soil_tests({"soil_tests": [{"soil": "Sand", "phi_deg": 85.0, "phi_std_deg": 1.0}]}))
    with pytest.raises(ValueError, match=r"the soil test of Sand I_d=20% puts phi in \[83, 87\] °, outside what the FEE"):
        fit_fixed(steep, AugmentedFEE())
    with pytest.raises(ValueError, match="no soil test matches a soil of the bags"):
        hold_theta(frame, parse_soil_tests({"soil_tests": [{"soil": "Peat", "phi_deg": 20.0, "phi_std_deg": 1.0}]}))
    # some match, some not (a mistyped soil or density): those are named, not dropped in silence
    some = parse_soil_tests({"soil_tests": [
        {"soil": "Clay", "relative_density_pct": 80, "phi_deg": 26.0, "phi_std_deg": 1.0},
        {"soil": "Peat", "phi_deg": 20.0, "phi_std_deg": 1.0},
        {"soil": "Sand", "relative_density_pct": 55, "phi_deg": 33.0, "phi_std_deg": 1.0}]})
    assert len(hold_theta(frame, some).theta_boxes) == 1
    assert unmatched(frame, some) == ["Peat", "Sand I_d=55%"]
    # a test of every density that one of each density beats wherever it matches holds nothing either
    beaten = parse_soil_tests({"soil_tests": [{"soil": "Clay", "phi_deg": 20.0, "phi_std_deg": 1.0}] + [
        {"soil": "Clay", "relative_density_pct": i_d, "phi_deg": 22.0, "phi_std_deg": 1.0} for i_d in DENSITIES]})
    assert unmatched(frame, beaten) == ["Clay"]
    with pytest.raises(ValueError, match="no soil test matches"):  # grouped by γ: no label is read
        hold_theta(build_frame(adhesion, stride=8, group_by="gamma"), tests)


@pytest.mark.parametrize("data, said", [
    ({"tests": []}, "non-empty list 'soil_tests'"),
    ({"soil_tests": ["Clay"]}, "soil_tests[0] is 'Clay', not a mapping"),
    ({"soil_tests": [{"soil": "Clay", "phi": 20}]}, "unknown key(s) ['phi']"),
    ({"soil_tests": [{"soil": "Clay", "phi_deg": 20}]}, "'phi_deg' and 'phi_std_deg' go together"),
    ({"soil_tests": [{"soil": "Clay", "phi_deg": 20, "phi_std_deg": 0}]}, "phi_std_deg=0 must be > 0"),
    ({"soil_tests": [{"soil": "Clay", "phi_deg": float("nan"), "phi_std_deg": 1}]}, "phi_deg=nan is not a finite number"),
    ({"soil_tests": [{"soil": "Clay", "phi_deg": 120, "phi_std_deg": 1}]}, "phi_deg=120 outside [0, 90]"),
    ({"soil_tests": [{"soil": "Clay", "c_kpa": -1, "c_std_kpa": 1}]}, "c_kpa=-1 outside"),
    # Pa given as kPa: said as the likely slip, naming the field (it was an error about the FEE's fit box)
    ({"soil_tests": [{"soil": "Clay", "c_kpa": 6800, "c_std_kpa": 0.3}]},
     "soil_tests[0].c_kpa=6800 kPa is beyond any soil (more than 1000 kPa, a weak rock's): a cohesion in Pa? "
     "6800 Pa is 6.8 kPa"),
    ({"soil_tests": [{"soil": "Clay", "c_kpa": 6.8, "c_std_kpa": 3000}]}, "c_std_kpa=3000 kPa is beyond any soil"),
    ({"soil_tests": [{"soil": "Clay", "relative_density_pct": 150, "phi_deg": 20, "phi_std_deg": 1}]},
     "relative_density_pct=150 outside [0, 100]"),
    ({"soil_tests": [{"soil": "Clay"}]}, "gives no parameter"),
    ({"soil_tests": [{"soil": "", "phi_deg": 20, "phi_std_deg": 1}]}, "soil='' is not a soil label"),
    ({"soil_tests": [{"soil": "Clay", "phi_deg": 20, "phi_std_deg": 1}, {"soil": "clay", "c_kpa": 2, "c_std_kpa": 1}]},
     "a second entry for clay"),
])
def test_bad_soil_tests_are_refused_naming_the_entry(data, said):
    with pytest.raises(ValueError) as err:
        parse_soil_tests(data)
    assert said in str(err.value), str(err.value)


def test_cli_refuses_a_bad_soil_test_file_before_reading_bags(tmp_path, capsys):
    bad = tmp_path / "tests.yaml"
    bad.write_text(yaml.safe_dump({"soil_tests": [{"soil": "Clay", "phi_deg": 20, "phi_std_deg": -1}]}))
    assert cli_main([str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--soil-tests", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"soil tests {bad}: soil_tests[0].phi_std_deg=-1 must be > 0" in err and "not a directory" not in err, err
    assert cli_main([str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--soil-tests", str(tmp_path / "none.yaml")]) == 2
    assert "cannot read it" in capsys.readouterr().err
    broken = tmp_path / "broken.yaml"  # the parser's own words were 8 lines; one, with the place
    broken.write_text("soil_tests:\n  - soil: Clay\n    phi_deg: [20\n")
    assert cli_main([str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--soil-tests", str(broken)]) == 2
    (line,) = [ln for ln in capsys.readouterr().err.splitlines() if str(broken) in ln]
    assert f"soil tests {broken} is not YAML: " in line and "at line 4, column 1" in line, line
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump(lab_results()))
    assert len(load_soil_tests(good)) == 8
    exponent = tmp_path / "exponent.yaml"  # PyYAML reads 1e0 as a string: "is not a finite number" before
    exponent.write_text("soil_tests:\n  - {soil: Clay, phi_deg: 2e1, phi_std_deg: 1e0}\n")
    assert len(load_soil_tests(exponent)) == 1
    hidden_none = cli_main([str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--hidden", ","])
    assert hidden_none == 2 and "--hidden ',' names no term" in capsys.readouterr().err  # (an IndexError after the run)
