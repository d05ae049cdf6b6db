"""Which physics the plan reads the fused posterior through: the user's, or the estimator's own.

The posterior's φ, c, δ mean a soil only through the physics it was fitted with (the FEE and the
terms of the estimator's fusion config and model): read through the FEE alone, the default
world's 95 % F_x bound differed by 1.6× in an outside reader's planner run by hand. The
estimator says its physics on ``/soil/estimator/physics`` (``graph.EstimatorPhysics``, latched),
so a planner started by hand, or in another launch, plans with it as ``soil_launch`` would. A
``terms`` or ``bound_law`` the user gives stays theirs; where it differs from the estimator's the
planner says so. rclpy-free: the node calls ``planning_physics`` with what it heard.
"""
from __future__ import annotations

from dataclasses import dataclass

from soil_msgs_py.graph import EstimatorPhysics
from soil_physics.force_terms import parse_terms

from .planner import steady_cut_terms


@dataclass(frozen=True)
class PlanningPhysics:
    """The plan's ``terms`` ((name, k) pairs) and ``bound_law`` (() or 4 numbers), and ``notes``:
    what the node should say (a user's choice that differs from the estimator's, terms left out)."""

    terms: tuple[tuple[str, float], ...]
    bound_law: tuple[float, ...]
    adopted: bool  # something of the estimator's is used
    notes: tuple[str, ...] = ()


def planning_physics(own_terms, own_bound_law, announced: EstimatorPhysics | None, follow: bool) -> PlanningPhysics:
    """The physics to plan with: the user's ``own_terms`` / ``own_bound_law`` where given (not
    empty), else the estimator's ``announced`` ones (``follow``: the node's parameter
    ``follow_estimator_physics``). Terms on the blade's travel or time in soil, which a planned
    steady cut does not have, are left out and said. ValueError naming an announced term the
    planner does not know (the node then keeps what it heard before)."""
    own = parse_terms(own_terms)
    own_law = tuple(float(v) for v in own_bound_law or ())
    if not follow or announced is None:
        return PlanningPhysics(own, own_law, adopted=False)
    try:
        theirs, left_out = steady_cut_terms(announced.terms)
    except ValueError as err:
        raise ValueError(f"from {announced.source or 'the estimator'}: {err}") from None
    notes = []
    if left_out:
        notes.append(f"the estimator's {', '.join(left_out)} left out (on the travel or time in soil, which a planned "
                     "steady cut does not have)")
    if own and own != theirs:
        notes.append(f"planning with the terms given ({physics_text(own)}), not the estimator's ({physics_text(theirs)}): "
                     "its posterior's θ means another soil through them")
    if own_law and own_law != announced.bound_law:
        notes.append(f"planning with the bound_law given {list(own_law)}, not the estimator's "
                     f"{list(announced.bound_law) or '(none: the estimate model_std_*)'}")
    return PlanningPhysics(own or theirs, own_law or announced.bound_law,
                           adopted=not (own and own_law), notes=tuple(notes))


def physics_text(terms) -> str:
    """'FEE + name (k = 0.5)': the physics of (name, k) ``terms`` as the planner's log says it."""
    return "FEE" + "".join(f" + {n} (k = {k:g})" for n, k in terms)
