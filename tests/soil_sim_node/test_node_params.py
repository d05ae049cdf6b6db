"""The simulator node's parameter checks without a running ROS graph (no rclpy.init, no DDS):
the ``engine`` parameter is validated like ``world_mode`` and is fixed at start-up."""
from __future__ import annotations

import pytest
from rclpy.parameter import Parameter

from soil_sim_node.node import PARAMETERS, SimNode, check_engine
from soil_sim_node.simulator import ENGINES

pytestmark = pytest.mark.live


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


def test_a_start_over_sim_command_uses_the_named_path_and_may_name_the_soil_files_soils(tmp_path):
    """With parameter ``path`` the episodes cut it; a /sim/command start may clear it and name a custom soil."""
    from types import SimpleNamespace

    from soil_physics.soils import load_soil_file
    from soil_sim_node.simulator import SimConfig

    soils = tmp_path / "site.yaml"
    soils.write_text("soils:\n  - {name: Silt, phi_deg: [26, 34], cohesion_pa: [1000, 4000], "
                     "unit_weight_n_m3: [17000, 19500]}\n  - {name: Undrained, phi_deg: [0, 0], cohesion_pa: [3e4, 3e4], "
                     "unit_weight_n_m3: [17000, 17000]}\npaths:\n  site_a: ['0:Silt:30', '4:Clay:80']\n")
    custom, named = SimNode._load_soil_file(str(soils), "site_a", [])
    assert named == load_soil_file(soils).paths["site_a"]
    values = {**defaults(), "soil_file": str(soils), "path": "site_a"}
    node = SimpleNamespace(_value=values.__getitem__, custom_soils=custom, named_path=named, config=SimConfig())
    spec = SimNode._spec_from_params(node, {})
    assert (spec.soil, spec.relative_density_pct, len(spec.patches)) == ("Silt", 30.0, 2)
    with pytest.raises(ValueError, match=r"soil unused while parameter path='site_a' sets the soil along the path"):
        SimNode._spec_from_params(node, {"soil": "Clay"})
    spec = SimNode._spec_from_params(node, {"patches": [], "soil": "Silt", "relative_density_pct": 70.0})
    assert (spec.soil, spec.relative_density_pct, spec.patches) == ("Silt", 70.0, ())
    # ... as a /sim/command start says it (the refusal above tells the user to; the command once refused the field)
    from soil_msgs_py import graph as G

    cmd = G.SimCommand.from_json('{"action": "start", "patches": [], "soil": "Silt", "relative_density_pct": 70}')
    assert SimNode._spec_from_params(node, cmd.overrides).patches == ()
    cmd = G.SimCommand.from_json('{"action": "start", "patches": ["0:Sand:20", "3:Silt:40"]}')
    assert [p.soil for p in SimNode._spec_from_params(node, cmd.overrides).patches] == ["Sand", "Silt"]
    for bad, needle in (('"0:Sand:20"', "must be a list of patches"),
                        ('["3:Sand:20", "1:Silt:40"]', r"/sim/command: patches\[1\]\.x_start_m=1\.0 must be greater")):
        with pytest.raises(ValueError, match=needle):
            G.SimCommand.from_json('{"action": "start", "patches": ' + bad + "}")
    with pytest.raises(ValueError, match="soil 'Undrained' at I_d 70 %: phi=0° gives the FEE no failure wedge"):
        SimNode._spec_from_params(node, {"patches": [], "soil": "Undrained", "relative_density_pct": 70.0})
    with pytest.raises(ValueError, match=r"parameter path='site_a' cannot be combined with sequence_soils"):
        SimNode._validate_static({**values, "sequence_soils": ["Clay"]})
    for name, value in (("soil_file", ""), ("path", "site_a")):
        result = SimNode._on_set_parameters(None, [Parameter(name, value=value)])
        assert not result.successful and name in result.reason and "start-up" in result.reason
    # while the path gives the patches, a parameter set cannot replace or clear them (later episodes
    # would silently cut the path anyway, or another soil than start-up refused)
    for patches in ([], ["0:Sand:20"]):
        result = SimNode._on_set_parameters(node, [Parameter("patches", Parameter.Type.STRING_ARRAY, patches),
                                                   Parameter("soil", value="Clay")])
        assert not result.successful and f"patches={patches}" in result.reason and "path='site_a'" in result.reason


@pytest.mark.parametrize("name, value", [("settle_s", 1e300), ("settle_s", float("nan")), ("wait_timeout_s", -1.0),
                                         ("lockstep_timeout_s", float("inf"))])
def test_start_and_tick_waits_are_bounded(name, value):
    """A pause of 1e300 s was accepted and no episode ever started, without a word."""
    with pytest.raises(ValueError, match=f"parameter {name}=.* must be a number of seconds in"):
        SimNode._validate_static({**defaults(), name: value})
