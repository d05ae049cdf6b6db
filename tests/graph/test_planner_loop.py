"""The loop closed in the live graph: ``soil_launch --planner`` runs simulator, controller,
estimator, planner and recorder as separate processes on a loopback domain, along a path whose
soil changes. The planner's targets are in the bag and the controller cut to them."""
from __future__ import annotations

import subprocess

import numpy as np
import pytest

from soil_bag_tools.bag_io import find_episode_bags, read_episode, read_labelled_topic
from soil_bringup.launch import stop_logged_nodes
from soil_msgs_py import topics as T
from soil_msgs_py.params import OBSERVATION_FIELDS

from tests.ros_probe import BIN, loopback_env, next_domain_id

U_ZA = OBSERVATION_FIELDS.index("u_za")


@pytest.mark.timeout(180)
def test_soil_launch_with_the_planner_closes_the_loop_and_records_it(tmp_path):
    domain, bags = next_domain_id(), tmp_path / "bags"
    args = ["--planner", "--pacing", "realtime", "--record", str(bags), "--timeout", "120", "--domain-id", str(domain),
            "--sim-param", "patches:=['0:Sand:20','4.5:Clay:80']", "--sim-param", "duration_s:=8.0",
            "--sim-param", "world_mode:=fee", "--planner-param", "start_depth_m:=0.08"]
    log_path = tmp_path / "launch.log"
    with log_path.open("w") as log:
        proc = subprocess.Popen([str(BIN / "soil_launch"), *args], env=loopback_env(domain), stdout=log,
                                stderr=subprocess.STDOUT, text=True)
    try:
        rc = proc.wait(timeout=150)
    except subprocess.TimeoutExpired:
        proc.kill()
        rc = proc.wait(timeout=10)
    finally:
        stop_logged_nodes(log_path)
    out = log_path.read_text()
    assert rc == 0, out[-4000:]
    assert "[planner]" in out and "depth_source:=planner" in out and "following the planner's target depth" in out, out[-4000:]

    (bag,) = find_episode_bags(bags)
    ep = read_episode(bag)
    stamps, targets = read_labelled_topic(bag, T.TARGET_DEPTH.name, T.TARGET_DEPTH_FIELDS)
    plan_stamps, plans = read_labelled_topic(bag, T.PLAN.name, T.PLAN_FIELDS)
    assert len(plan_stamps) > 100 and len(stamps) >= 10 and np.isfinite(targets).all()
    assert targets[0, 0] == pytest.approx(0.08) and targets[:, 0].max() > 0.12  # started shallow, then deepened
    # Every blade command after the first target was cut to a planner target in effect then
    # (u_za = −(d̄ − Δd̄) >= −d̄), or to the parameter's 0.2 m in a moment without one.
    after = ep.stamps_ns >= stamps[0]
    u_za = ep.observations[after, U_ZA]
    latest = np.searchsorted(stamps, ep.stamps_ns[after], side="right") - 1
    followed = np.isclose(u_za, -targets[latest, 0], atol=1e-9) | (u_za > -targets[latest, 0])
    assert followed.mean() > 0.9, (followed.mean(), u_za[:20], targets[:5])
    assert (np.abs(u_za + 0.2) > 1e-6).mean() > 0.5  # mostly not the parameter's depth
