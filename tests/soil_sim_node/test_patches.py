"""Soil patches along x (``EpisodeSpec.patches``): validation, the soil switching under the
blade's edge in both engines, what the blade carries across a boundary, and soil_sim_batch's
bags with their patches. Short episodes (the blade starts at x = 2 m)."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from soil_bag_tools.bag_io import find_episode_bags, read_episode
from soil_msgs_py.params import GROUND_TRUTH_PARAMS, KNOWN_PARAMS
from soil_msgs_py.patches import SoilPatch
from soil_physics.soils import get_soil
from soil_sim_node import batch
from soil_sim_node.plot import plot_episode
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig, SoilSimulator

BOUNDARY_M = 2.6
PATH = ("0.0:Sand:20", f"{BOUNDARY_M}:Clay:90")


def spec(patches=PATH, duration_s: float = 2.5, **kw) -> EpisodeSpec:
    return EpisodeSpec("Loam", 60.0, 0.8, 0.2, kw.pop("seed", 5), duration_s, patches=patches, **kw)


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize("patches, needle", [
    (("3.0:Sand:20", "2.0:Clay:90"), r"patches\[1\]\.x_start_m=2\.0 must be greater than patches\[0\]\.x_start_m=3\.0"),
    (("0:Sand:20", "0:Clay:90"), r"patches\[1\]\.x_start_m=0\.0 must be greater"),
    (("0:Sand:20", "4:Mud:90"), r"patches\[1\]: soil='Mud' is unknown"),
    (("0:Sand:120",), r"patches\[0\]\.relative_density_pct=120\.0 outside \[0, 100\]"),
    (((0.0, "Sand", -1.0),), r"patches\[0\]\.relative_density_pct=-1\.0 outside"),
    (((0.0, "Sand", math.nan),), r"patches\[0\]\.relative_density_pct=nan outside"),
    (("0:Sand:20", "inf:Clay:90"), r"patches\[1\]\.x_start_m=inf must be a finite number"),
    (((math.nan, "Sand", 20.0),), r"patches\[0\]\.x_start_m=nan must be a finite number"),
    (((True, "Sand", 20.0),), r"patches\[0\]\.x_start_m=True must be a finite number"),
    (("0:Sand",), r"patches\[0\]='0:Sand' must look like 'X:SOIL:ID'"),
    (("zero:Sand:20",), r"patches\[0\]='zero:Sand:20': x_start_m and relative_density_pct must be numbers"),
    (({"x": 0.0, "soil": "Sand", "relative_density_pct": 2.0},), r"patches\[0\]=.* must have exactly the keys"),
    (((0.0, "", 20.0),), r"patches\[0\]\.soil='' must be a soil name"),
])
def test_bad_patches_are_refused_naming_the_field_and_value(patches, needle):
    with pytest.raises(ValueError, match=needle):
        spec(patches).resolve()


def test_resolve_takes_the_first_patch_as_the_episodes_soil_and_names_soils_as_the_catalogue():
    resolved, soil = spec(("-1:sand:20", "5:CLAY:90.5")).resolve()
    assert (resolved.soil, resolved.relative_density_pct, soil.name) == ("Sand", 20.0, "Sand")
    assert resolved.patches == (SoilPatch(-1.0, "Sand", 20.0), SoilPatch(5.0, "Clay", 90.5))
    plain = EpisodeSpec("Loam", 60.0, 0.8, 0.2, 5, 2.5)
    assert plain.resolve()[0] is plain and plain.patches == ()


def test_an_episode_is_named_after_the_patch_its_edge_starts_in_and_its_truth_is_that_soils():
    """'0:Sand:20, 1.5:Clay:90': the edge starts at x = 2 m, in the clay; the sand is never cut,
    yet it named and labelled the episode (an outside reviewer's)."""
    behind = spec(("0:Sand:20", "1.5:Clay:90"))
    resolved, soil = behind.resolve()
    assert (resolved.soil, resolved.relative_density_pct, soil.name) == ("Clay", 90.0, "Clay")
    assert resolved.patches == (SoilPatch(0.0, "Sand", 20.0), SoilPatch(1.5, "Clay", 90.0))
    ep = run_episodes(SimConfig(world_mode="fee"), [replace(behind, duration_s=1.0)])[0]
    assert (ep.meta.soil, ep.meta.relative_density_pct) == ("Clay", 90.0) and ep.meta.name.startswith("fee_clay_id090_")
    assert np.allclose(ep.truth[:, 0], get_soil("Clay").at(90.0).phi)
    for boundary, first in ((2.0, "Clay"), (2.5, "Sand")):  # at the edge's start: the later patch holds there
        assert spec(("0:Sand:20", f"{boundary}:Clay:90")).resolve()[0].soil == first, boundary


def test_a_negative_zero_density_is_the_same_grid_point_as_zero():
    """'-0' (a CLI list, a patch) had named a bag id-00 beside the id000 of the same soil."""
    negative = EpisodeSpec("Sand", -0.0, 0.5, 0.1, 0, 2.0, patches=("-0:Sand:-0", "5:Clay:50"))
    resolved, _ = negative.resolve()
    assert math.copysign(1.0, resolved.relative_density_pct) == 1.0
    assert all(math.copysign(1.0, v) == 1.0 for v in (resolved.patches[0].x_start_m, resolved.patches[0].relative_density_pct))
    assert run_episodes(SimConfig(world_mode="fee"), [negative])[0].meta.name.startswith("fee_sand_id000_")


# ------------------------------------------------------------------ the physics
def _step_at_boundary(ep):
    """Index of the first tick whose edge is past the boundary."""
    x = ep.column("p_x_b")
    k = int(np.argmax(x >= BOUNDARY_M))
    assert k > 30 and x[-1] > BOUNDARY_M + 0.3, "the blade must cut before and after the boundary"
    return k


@pytest.mark.parametrize("world", ["fee", "default"])
@pytest.mark.parametrize("engine", ["compiled", "reference"])
def test_force_and_ground_truth_change_where_the_edge_crosses_a_boundary(world, engine):
    (ep,) = run_episodes(SimConfig(world_mode=world, engine=engine), [spec()])
    k = _step_at_boundary(ep)
    sand, clay = get_soil("Sand").at(20.0), get_soil("Clay").at(90.0)
    columns = [(ep.truth, GROUND_TRUTH_PARAMS, name) for name in ("phi", "c", "gamma")] + [(ep.known, KNOWN_PARAMS, "gamma")]
    for rows, names, name in columns:
        values = rows[:, names.index(name)]
        np.testing.assert_allclose(values[:k], getattr(sand, name), rtol=1e-12, err_msg=name)
        np.testing.assert_allclose(values[k:], getattr(clay, name), rtol=1e-12, err_msg=name)
    beta = ep.column("beta")
    assert np.all(np.abs(np.diff(beta[k - 5:k])) < 1e-3) and abs(beta[k] - beta[k - 1]) > 1e-2  # β* steps with φ
    fx = ep.forces[:, 0]
    assert fx[k + 2:k + 20].mean() > 2.5 * fx[k - 20:k].mean() > 0  # dense clay resists far more than loose sand


def test_the_pile_and_compaction_across_a_boundary():
    """The surcharge pile keeps what it holds (Q continuous) and mixes in the new soil; the new
    patch's compaction starts from its own I_d."""
    sim = SoilSimulator(SimConfig(world_mode="default"), [spec(duration_s=3.0)])
    sand, clay = get_soil("Sand").at(20.0), get_soil("Clay").at(90.0)
    q, gamma, x_b, i_d = [], [], [], []
    out = sim.reset()
    for _ in range(150):
        x_b.append(out.positions[0, 0])
        q.append(out.known[0, 6])
        gamma.append(sim.pile_gamma[0])
        i_d.append(sim.soil_in_effect()[3][0])
        out = sim.step(-0.25, -0.2, 0.8)  # lift joint down, full speed: cutting all the way
    x_b, q, gamma, i_d = map(np.array, (x_b, q, gamma, i_d))
    k = int(np.argmax(x_b >= BOUNDARY_M))
    assert 30 < k < 140 and q[k - 1] > 1e3
    assert np.all(gamma[:k] == sand.gamma)  # bit for bit: a one-soil pile never changes its gamma
    assert sand.gamma < gamma[k + 1] < gamma[-1] < clay.gamma  # the clay mixes in
    assert abs(q[k] - q[k - 1]) < 3 * np.abs(np.diff(q[k - 10:k - 1])).max()  # no jump at the boundary
    assert i_d[k - 1] > 20.0 + 1.0  # sand compacted on its way
    assert 90.0 < i_d[k + 1] < 90.0 + 0.5  # the clay starts from its own I_d, not from the sand's travel


def test_episodes_without_patches_are_unchanged_by_a_patched_neighbour_in_the_batch():
    plain = EpisodeSpec("Clay", 70.0, 0.6, 0.2, 9, 1.0)
    (alone,) = run_episodes(SimConfig(), [plain])
    together = run_episodes(SimConfig(), [spec(duration_s=1.0), plain])
    for name in ("observations", "forces", "known", "truth", "extras"):
        np.testing.assert_array_equal(getattr(together[1], name), getattr(alone, name), err_msg=name)
    assert alone.meta.patches == [] and "patches" not in json.loads(alone.meta.to_json())


# ------------------------------------------------------------------ soil_sim_batch and bags
def test_soil_sim_batch_bag_records_the_patches_and_the_truth_steps(tmp_path, capsys):
    out = tmp_path / "bags"
    assert batch.main(["--mode", "fee", "--out", str(out), "--patch", "0:sand:20", "--patch", f"{BOUNDARY_M}:Clay:90",
                       "--speeds", "0.8", "--depths", "0.2", "--seeds", "1", "--duration", "2.5", "--workers", "1",
                       "--quiet"]) == 0
    (bag,) = find_episode_bags(out)
    ep = read_episode(bag)
    assert ep.meta.soil_patches() == (SoilPatch(0.0, "Sand", 20.0), SoilPatch(BOUNDARY_M, "Clay", 90.0))
    assert (ep.meta.soil, ep.meta.relative_density_pct) == ("Sand", 20.0) and bag.name.startswith("fee_sand_id020_")
    assert bag.name == ep.meta.name and "_p2-" in bag.name
    k = _step_at_boundary(ep)
    phi = ep.column("phi")
    assert set(phi[:k]) == {get_soil("Sand").at(20.0).phi} and set(phi[k:]) == {get_soil("Clay").at(90.0).phi}
    summary = json.loads((out / "dataset.json").read_text())
    assert summary["soil_paths"] == [[p.as_dict() for p in ep.meta.soil_patches()]]
    (want,) = run_episodes(SimConfig(world_mode="fee"), [EpisodeSpec("Gravel", 1.0, 0.8, 0.2, 0, 2.5, patches=PATH)])
    np.testing.assert_array_equal(ep.forces, want.forces)  # the soil/I_d the patches replace play no part
    assert plot_episode(ep, tmp_path / "fig.png").stat().st_size > 10_000  # the boundary marked in the figure


def test_soil_sim_batch_takes_a_named_path_of_the_soil_file(tmp_path):
    soil_file = tmp_path / "site.yaml"
    soil_file.write_text(yaml.safe_dump({
        "soils": [{"name": "SiltyClay", "phi_deg": [20, 30], "cohesion_pa": [3000, 9000],
                   "unit_weight_n_m3": [16000, 20000]}],
        "paths": {"site_a": ["0.0:Sand:20", "4.0:SiltyClay:90"]},
    }))
    args = ["--soil-file", str(soil_file), "--out", str(tmp_path / "bags"), "--speeds", "0.5", "--depths", "0.1,0.2"]
    plan = batch.plan_from_args(batch.parse_args([*args, "--path", "site_a"]))
    assert len(plan.specs) == 2 * batch.DEFAULT_SEEDS
    assert {s.patches for s in plan.specs} == {(SoilPatch(0.0, "Sand", 20.0), SoilPatch(4.0, "SiltyClay", 90.0))}
    for spec_ in plan.specs:
        spec_.resolve(plan.custom_soils)
    with pytest.raises(ValueError, match=r"--path='site_b' is not a path of --soil-file=.*; its paths: \['site_a'\]"):
        batch.plan_from_args(batch.parse_args([*args, "--path", "site_b"]))


@pytest.mark.parametrize("argv, needle", [
    (["--patch", "0:Sand:20", "--patch", "2:Mud:90"], "--patch[1]='2:Mud:90': soil='Mud' is unknown"),
    (["--patch", "3:Sand:20", "--patch", "2:Clay:90"], "--patch[1].x_start_m=2.0 must be greater than"),
    (["--patch", "0:Sand:20", "--soils", "Clay"], "--soils cannot be combined with --patch or --path"),
    (["--patch", "0:Sand:20", "--relative-densities", "20"], "--relative-densities cannot be combined"),
    (["--patch", "0:Sand:101"], "--patch[0].relative_density_pct=101.0 outside [0, 100] %"),
    (["--path", "a"], "--path='a' needs --soil-file"),
    (["--relative-densities", "abc"], "--relative-densities='abc' must be a comma-separated list of numbers"),
    (["--depths", "0.1,x"], "--depths='0.1,x' must be a comma-separated list of numbers"),
    # a value left out was dropped without a word; a depth that only skims the surface made an episode without a cut
    (["--depths", "0.1,,0.2"], "--depths='0.1,,0.2': item 2 is empty"),
    (["--speeds", "0.5,"], "--speeds='0.5,': item 2 is empty"),
    (["--depths", "0.1,0.005"], "--depths 0.005: the blade cuts from 0.01 m"),
    (["--depths", "0"], "--depths 0: the blade cuts from 0.01 m"),
    # an outside tester's: an empty soil was dropped where an empty speed is refused; a seed base whose
    # last episode's seed overflowed was named as that seed, not as --seed-base; a plugin's k given twice
    (["--soils", "Clay,,Sand"], "--soils='Clay,,Sand': item 2 is empty"),
    (["--soils", "Clay", "--depths", "0.1,0.2", "--seed-base", str(2**63 - 1)], "--seed-base=9223372036854775807 must be in"),
    (["--soils", "Clay", "--plugin", "soil_physics.force_terms:plugin term=soil_inertia k=1 k=2"], "parameter 'k' is given twice"),
])
def test_soil_sim_batch_refuses_bad_patches_before_writing(tmp_path, capsys, argv, needle):
    out = tmp_path / "never"
    assert batch.main([*argv, "--out", str(out), "--quiet"]) == 2
    assert needle in capsys.readouterr().err
    assert not out.exists()
