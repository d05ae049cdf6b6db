"""The planner reads the fused posterior through the estimator's own physics, which the estimator
says on /soil/estimator/physics: a planner run by hand had read it through the FEE alone (the
default world's 95 % F_x bound 1.6× off in an outside reader's run), and soil_launch had worked
out the estimator's physics on its own, without the checkpoint's terms."""
from __future__ import annotations

import pytest

from soil_msgs_py import graph as G
from soil_planner.estimator_physics import planning_physics

FORM = "form:-qnq*tanhvx0.1=0.756"


def said(terms=(FORM,), law=(300.0, 5.0, 0.07, 2.0)) -> G.EstimatorPhysics:
    return G.EstimatorPhysics(terms=tuple(terms), bound_law=tuple(law), source="fusion_default.json")


def test_what_the_estimator_says_is_what_its_posterior_runs():
    """The shipped default world's posterior: its term and bound law; the fee world's: the FEE alone and
    its own law; a config given wins over the checkpoint's world; one without a bound law says none;
    a model's own catalogue terms come first."""
    import dataclasses

    from pinn_estimator.checkpoint import DEFAULT_CHECKPOINT, load_model
    from pinn_estimator.fusion_config import FusionConfig
    from pinn_estimator.fusion_calibration import (announced_physics, checkpoint_world, config_for_model, config_path,
                                                   estimator_fusion)

    model, ckpt = load_model(str(DEFAULT_CHECKPOINT))
    fee_model, fee_ckpt = load_model(str(DEFAULT_CHECKPOINT.with_name("pinn_fee.pt")))

    def announced(path, m, c):
        return announced_physics(config_for_model(estimator_fusion(path, c)[0], m), "src")

    default = announced("", model, ckpt)
    law = FusionConfig.load(config_path("default")).planner_bound_law()
    assert default.terms and default.terms[0].startswith("form:") and default.bound_law == law
    fee = announced("", fee_model, fee_ckpt)
    assert fee.terms == () and fee.bound_law == FusionConfig.load(config_path("fee")).planner_bound_law()
    assert announced(str(config_path("default")), fee_model, fee_ckpt) == default
    assert G.EstimatorPhysics.from_json(default.to_json()) == default
    assert announced_physics(FusionConfig(), "").bound_law == ()  # a config from before the bound law
    model.cfg = dataclasses.replace(model.cfg, extra_terms=(("soil_inertia", 2.0),))  # a model retrained with a term
    assert announced("", model, ckpt).terms[0] == "soil_inertia=2.0"
    assert checkpoint_world({"dataset": {"world_modes": ["fee"]}}) == "fee"
    for worlds in (["fee", "default"], [], ["mars"], None):
        assert checkpoint_world({"dataset": {"world_modes": worlds}}) == "default"


def test_the_users_own_physics_stays_and_what_differs_is_said():
    choice = planning_physics([], [], said(), follow=True)
    assert choice.terms == (("form:-qnq*tanhvx0.1", 0.756),) and choice.bound_law == (300.0, 5.0, 0.07, 2.0)
    assert choice.adopted and not choice.notes
    assert planning_physics([], [], None, follow=True).terms == ()  # nothing said yet: the FEE alone
    assert planning_physics([], [], said(), follow=False).terms == ()
    mine = planning_physics(["soil_inertia=2.0"], [], said(), follow=True)
    assert mine.terms == (("soil_inertia", 2.0),) and mine.bound_law == (300.0, 5.0, 0.07, 2.0) and mine.adopted
    assert "not the estimator's" in mine.notes[0] and "form:-qnq*tanhvx0.1" in mine.notes[0]
    both = planning_physics([FORM], [1.0, 2.0, 0.1, 0.2], said(), follow=True)
    assert not both.adopted and both.bound_law == (1.0, 2.0, 0.1, 0.2) and len(both.notes) == 1
    travel = planning_physics([], [], said((FORM, "compaction_hardening=0.1")), follow=True)
    assert travel.terms == (("form:-qnq*tanhvx0.1", 0.756),) and "compaction_hardening" in travel.notes[0]
    with pytest.raises(ValueError, match="from fusion_default.json: .*no_such_term"):
        planning_physics([], [], said(("no_such_term=1.0",)), follow=True)


def test_an_announcement_the_planner_cannot_plan_with_keeps_the_physics_heard_before():
    """A well-formed announcement with an unknown term dropped the estimator's physics for the rest
    of the run, the plans then read through the FEE alone (an outside tester's)."""
    from types import SimpleNamespace

    from std_msgs.msg import String

    from soil_planner.node import PlannerNode
    from soil_planner.stretch_planner import from_parameters

    good = said()
    taken, warned = [], []
    node = SimpleNamespace(own_physics={"terms": [], "bound_law": []}, announced=good, _warn=lambda k, t: warned.append(t),
                           planner=from_parameters({"margin": 0.85, "d_max_m": 0.3, "cut_speed_m_s": 0.5,
                                                    "include_residual": True, "force_quantile": 0.95, "terms": [],
                                                    "sensor_anchor": True, "bound_law": []}),
                           _take_physics=lambda: taken.append(node.announced))
    for bad in (said(("no_such_term=1.0",)), said(law=(1e12, 5.0, 0.1, 0.2))):
        PlannerNode._on_physics(node, String(data=bad.to_json()))
        assert node.announced is good and not taken and "not taken, the plans' physics stays" in warned[-1], warned
    PlannerNode._on_physics(node, String(data="not json {"))
    assert node.announced is good and len(warned) == 3
    fee = said((), (5.0, 5.0, 0.0, 0.0))
    PlannerNode._on_physics(node, String(data=fee.to_json()))
    assert node.announced == fee and taken == [fee]


@pytest.mark.parametrize("text, field", [
    ("[]", "JSON object"), ('{"terms": "a=1", "bound_law": []}', "terms="),
    ('{"terms": ["a"], "bound_law": []}', "terms="), ('{"terms": [], "bound_law": [1, 2]}', "bound_law="),
    ('{"terms": [], "bound_law": [1, 2, 3, NaN]}', "bound_law="), ('{"terms": [], "bound_law": [1, 2, 3, -4]}', "bound_law="),
    ('{"terms": [], "bound_law": [' + "9" * 400 + ', 1, 1, 1]}', "bound_law="),  # (no float: an OverflowError)
    ('{"terms": [], "bound_law": [], "extra": 1}', "unknown field"), ('{"terms": [], "bound_law": [], "source": 3}', "source=")])
def test_a_bad_announcement_is_refused_naming_the_field(text, field):
    with pytest.raises(ValueError, match=field.replace("[", r"\[")):
        G.EstimatorPhysics.from_json(text)
