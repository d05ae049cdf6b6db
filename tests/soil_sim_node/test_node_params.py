"""The simulator node's parameter checks without a running ROS graph (no rclpy.init, no DDS):
the ``engine`` parameter is validated like ``world_mode`` and is fixed at start-up."""
from __future__ import annotations

import pytest
from rclpy.parameter import Parameter

from soil_sim_node.node import PARAMETERS, SimNode, check_engine
from soil_sim_node.simulator import ENGINES


def defaults() -> dict:
    return {name: spec[0] for name, spec in PARAMETERS.items()}


def test_engine_parameter_defaults_to_compiled_and_accepts_every_engine():
    assert PARAMETERS["engine"][0] == "compiled" == ENGINES[0]
    for engine in ENGINES:
        SimNode._validate_static({**defaults(), "engine": engine})


@pytest.mark.parametrize("bad", ["turbo", "Compiled", "", 3])
def test_unknown_engine_is_refused_naming_the_parameter_and_value(bad):
    with pytest.raises(ValueError, match=rf"parameter engine={bad!r} is not one of"):
        SimNode._validate_static({**defaults(), "engine": bad})
    with pytest.raises(ValueError, match="engine"):
        check_engine(bad)


def test_engine_can_only_be_set_at_start_up():
    result = SimNode._on_set_parameters(None, [Parameter("engine", value="reference")])
    assert not result.successful and "engine" in result.reason and "start-up" in result.reason


def test_patches_parameter_defaults_to_none_and_is_refused_with_a_sequence_plan():
    assert PARAMETERS["patches"][0] == []
    SimNode._validate_static({**defaults(), "patches": ["0:Sand:20", "5:Clay:90"]})
    for plan in ("sequence_soils", "sequence_relative_densities_pct"):
        with pytest.raises(ValueError, match=rf"parameter patches=\['0:Sand:20'\] cannot be combined with {plan}"):
            SimNode._validate_static({**defaults(), "patches": ["0:Sand:20"], plan: ["Clay"]})
