"""A planner started by hand hears the estimator's posterior physics (latched, on joining) and plans
with it, as under soil_launch (tests/soil_planner/test_estimator_physics.py: what is said and taken)."""
from __future__ import annotations

import time

import pytest

from tests.ros_probe import NodeProc, next_domain_id, wait_until

pytestmark = pytest.mark.live


@pytest.mark.timeout(180)
def test_a_planner_started_by_hand_after_the_estimator_plans_with_its_physics(tmp_path):
    """No launcher: the estimator runs, then a planner is started by hand with no terms; it hears the
    latched physics on joining. Given follow_estimator_physics false, it keeps the FEE alone."""
    domain = next_domain_id()
    estimator = NodeProc("pinn_estimator", [], domain, tmp_path)
    planners = []
    try:
        wait_until(lambda: "publishing" in estimator.output, 120, "the estimator's start line")
        planners = [NodeProc("soil_planner", ["--ros-args", "-p", "inputs_wait_s:=0.0"], domain, tmp_path),
                    NodeProc("soil_planner", ["--ros-args", "-r", "__node:=fee_alone", "-p", "inputs_wait_s:=0.0",
                                              "-p", "follow_estimator_physics:=false"], domain, tmp_path)]
        wait_until(lambda: "plans read the posterior through" in planners[0].output, 60,
                   "the planner taking the estimator's physics")
        time.sleep(1.0)
    finally:
        for node in planners:
            assert node.stop() == 0, node.output
        assert estimator.stop() == 0, estimator.output
    out = planners[0].output
    assert "FEE + form:-qnq*tanhvx0.1 (k = 0.756) (the estimator's)" in out and "fusion_default.json" in out, out
    assert "until the estimator says its own" in out, out
    assert "plans read the posterior through" not in planners[1].output and "physics FEE," in planners[1].output
