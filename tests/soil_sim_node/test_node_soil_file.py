"""The simulator node's ``soil_file`` and ``path`` parameters, live: a custom soil and a named
path from a soils YAML, as a user starts them (real node processes over DDS on loopback)."""
from __future__ import annotations

import pytest

from soil_msgs_py.patches import SoilPatch
from soil_physics.soils import load_soil_file
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig
from tests.ros_probe import NodeProc, next_domain_id
from tests.soil_sim_node.test_node_patches import assert_same_arrays, lockstep_episode

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]
SOILS_YAML = """\
soils:
  - {name: Silt, phi_deg: [26, 34], cohesion_pa: [1000, 4000], unit_weight_n_m3: [17000, 19500]}
paths:
  silt_then_clay: ["0.0:Silt:30", "2.6:Clay:90"]
"""


@pytest.fixture
def soil_file(tmp_path):
    path = tmp_path / "my_soils.yaml"
    path.write_text(SOILS_YAML)
    return path


def test_lockstep_run_on_a_named_path_of_a_soil_file_equals_the_batch(tmp_path, soil_file):
    """The path's custom soil is simulated (its truth in the bag) exactly as soil_sim_batch
    --soil-file --path simulates it."""
    _, live = lockstep_episode(tmp_path, f"soil_file:={soil_file}", "path:=silt_then_clay")
    assert live.meta.soil_patches() == (SoilPatch(0.0, "Silt", 30.0), SoilPatch(2.6, "Clay", 90.0))
    custom = load_soil_file(soil_file).soils
    spec = EpisodeSpec("Loam", 60.0, 0.8, 0.2, 4, 2.5, patches=["0.0:Silt:30", "2.6:Clay:90"])
    (ref,) = run_episodes(SimConfig(), [spec], custom_soils=custom)
    assert_same_arrays(live, ref)
    assert custom["Silt"].at(30.0).phi in set(live.column("phi"))  # the custom soil was cut


@pytest.mark.parametrize("params, needle", [
    (["soil:=Silt"], "soil='Silt' is unknown"),  # a custom soil without its file
    (["soil_file:=/nowhere/soils.yaml"], "parameter soil_file='/nowhere/soils.yaml': soil file '/nowhere/soils.yaml' does not exist"),
    (["path:=silt_then_clay"], "parameter path='silt_then_clay' needs parameter soil_file"),
    (["soil_file:={file}", "path:=clay_then_silt"], "parameter path='clay_then_silt' is not a path of parameter soil_file="),
    (["soil_file:={file}", "path:=silt_then_clay", "patches:=['0:Sand:20']"], "both give the patches"),
    # a plan's entry is named with its list and index (the spec's error named only soil or relative_density_pct)
    (["sequence_soils:=['Clay','Mud']"], "parameter sequence_soils[1]='Mud': soil='Mud' is unknown"),
    (["sequence_relative_densities_pct:=[20.0, 200.0]"],
     "parameter sequence_relative_densities_pct[1]=200.0: relative_density_pct=200.0 outside"),
])
def test_bad_soil_file_parameters_are_refused_at_start_naming_them(tmp_path, soil_file, params, needle):
    args = ["--ros-args"]
    for p in params:
        args += ["-p", p.format(file=soil_file)]
    sim = NodeProc("soil_sim_node", args, next_domain_id(), tmp_path)
    try:
        assert sim.wait(timeout=60) == 2, sim.output
    finally:
        sim.stop()
    assert "cannot start" in sim.output and needle in sim.output and "Traceback" not in sim.output


def test_a_custom_soil_as_the_episodes_soil(tmp_path, soil_file):
    """``soil`` names a soil of the file; the node starts (and exits when done) without a controller
    in real time, so this only checks the episode is announced with that soil."""
    sim = NodeProc("soil_sim_node", ["--ros-args", "-p", f"soil_file:={soil_file}", "-p", "soil:=Silt",
                                     "-p", "relative_density_pct:=50.0", "-p", "duration_s:=0.5",
                                     "-p", "exit_when_done:=true", "-p", "engine:=reference"],
                   next_domain_id(), tmp_path)
    try:
        assert sim.wait(timeout=60) == 0, sim.output
    finally:
        sim.stop()
    assert "episode 0 start: default_silt_id050" in sim.output and "Traceback" not in sim.output
