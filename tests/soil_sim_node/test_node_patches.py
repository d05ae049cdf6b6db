"""The simulator node's ``patches`` parameter, live: real node processes over DDS on loopback
(own ROS_DOMAIN_ID per test), as a user starts them."""
from __future__ import annotations

import subprocess

import numpy as np
import pytest

from soil_bag_tools.bag_io import find_episode_bags, read_episode
from soil_msgs_py.patches import SoilPatch
from soil_physics.soils import get_soil
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig
from tests.ros_probe import BIN, NodeProc, loopback_env, next_domain_id

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]
PATCHES = ["0.0:Sand:20", "2.6:Clay:90"]


def lockstep_episode(tmp_path, *sim_params: str):
    """(the one episode bag, its Episode) of a lockstep ``soil_launch`` with ``sim_params``
    ('name:=value') and 2.5 s at 0.8 m/s, seed 4, recorded under tmp_path/bags."""
    log = tmp_path / "launch.log"
    domain = next_domain_id()
    args = [a for p in (*sim_params, "duration_s:=2.5", "target_speed_m_s:=0.8", "seed:=4") for a in ("--sim-param", p)]
    with log.open("w") as out:
        proc = subprocess.run([str(BIN / "soil_launch"), "--domain-id", str(domain), "--pacing", "lockstep",
                               "--record", str(tmp_path / "bags"), "--timeout", "90", *args],
                              env=loopback_env(domain), stdout=out, stderr=subprocess.STDOUT, timeout=110)
    assert proc.returncode == 0, log.read_text()
    (bag,) = find_episode_bags(tmp_path / "bags")
    return bag, read_episode(bag)


def assert_same_arrays(live, ref) -> None:
    for name in ("observations", "forces", "known", "truth", "extras"):
        np.testing.assert_array_equal(getattr(live, name), getattr(ref, name), err_msg=name)


def test_lockstep_run_with_patches_records_them_and_equals_the_batch(tmp_path):
    bag, live = lockstep_episode(tmp_path, "patches:=[" + ",".join(f"'{p}'" for p in PATCHES) + "]")
    assert live.meta.soil_patches() == (SoilPatch(0.0, "Sand", 20.0), SoilPatch(2.6, "Clay", 90.0))
    assert (live.meta.soil, live.meta.relative_density_pct, live.meta.source) == ("Sand", 20.0, "soil_sim_node")
    (ref,) = run_episodes(SimConfig(), [EpisodeSpec("Loam", 60.0, 0.8, 0.2, 4, 2.5, patches=PATCHES)])
    assert live.meta.name == ref.meta.name == bag.name
    assert_same_arrays(live, ref)
    phi = set(live.column("phi"))
    assert phi == {get_soil("Sand").at(20.0).phi, get_soil("Clay").at(90.0).phi}  # the truth steps


@pytest.mark.parametrize("value, needle", [
    ("['0:Sand:20','2:Mud:90']", "patches[1]: soil='Mud' is unknown"),
    ("['3:Sand:20','2:Clay:90']", "patches[1].x_start_m=2.0 must be greater than patches[0].x_start_m=3.0"),
    ("['0:Sand']", "patches[0]='0:Sand' must look like 'X:SOIL:ID'"),
])
def test_bad_patches_parameter_is_refused_at_start_naming_it(tmp_path, value, needle):
    sim = NodeProc("soil_sim_node", ["--ros-args", "-p", f"patches:={value}"], next_domain_id(), tmp_path)
    try:
        assert sim.wait(timeout=60) == 2, sim.output
    finally:
        sim.stop()
    assert "cannot start" in sim.output and needle in sim.output and "Traceback" not in sim.output
