"""Property-based tests of the simulator's gates: the command gate and the checks of episode
and node parameters. Whatever a client sends, the core gets finite commands in range, and a
bad parameter is a ValueError naming it, never another exception."""
from __future__ import annotations

import math

import pytest

from hypothesis import given, settings
from hypothesis import strategies as st

from soil_msgs_py import graph as G
from soil_sim_node.live import COMMAND_LIMITS, COMMAND_TOPIC_FIELDS, CommandGate
from soil_sim_node.pacing import PACINGS, check_pacing
from soil_sim_node.simulator import EpisodeSpec

FUZZ = settings(max_examples=150, deadline=None, derandomize=True, database=None)
any_float = st.floats(allow_nan=True, allow_infinity=True)
stamps = st.integers(min_value=0, max_value=50)
step = st.one_of(
    st.tuples(st.just("expect"), stamps),
    st.tuples(st.just("idle"), st.none()),
    st.tuples(st.sampled_from(G.COMMAND_TOPICS), stamps, st.lists(any_float, min_size=2, max_size=2)),
)


@FUZZ
@given(st.lists(step, max_size=60))
def test_command_gate_never_raises_and_hands_the_core_finite_commands_in_range(steps):
    gate = CommandGate()
    expected, arrived = None, set()
    for s in steps:
        if s[0] == "expect":
            gate.expect(s[1])
            expected, arrived = s[1], set()
        elif s[0] == "idle":
            gate.idle()
            expected, arrived = None, set()
        else:
            topic, stamp, values = s
            warnings = gate.offer(topic, stamp, values[: len(COMMAND_TOPIC_FIELDS[topic])])
            assert all(isinstance(k, str) and isinstance(t, str) for k, t in warnings)
            if expected is not None and stamp == expected and topic not in arrived:
                arrived.add(topic)  # the one command per topic the gate takes
            elif warnings == []:
                raise AssertionError(f"{topic} stamped {stamp} taken while expecting {expected}")
        assert gate.complete == (arrived == set(G.COMMAND_TOPICS))
        u_zr, u_za, u_x = gate.take()
        for name, value in (("u_zr", u_zr), ("u_za", u_za), ("u_x", u_x)):
            lo, hi = COMMAND_LIMITS[name]
            assert math.isfinite(value) and lo <= value <= hi, (name, value)


spec_value = st.one_of(any_float, st.integers(-(10**20), 10**20), st.text(max_size=5), st.none(), st.booleans())


@FUZZ
@given(st.one_of(st.sampled_from(["Clay", "loam", "Sand", "Gravel"]), st.text(max_size=8)),
       spec_value, spec_value, spec_value, spec_value, spec_value)
def test_episode_spec_checks_accept_in_range_or_name_the_field(soil, density, speed, depth, seed, duration):
    spec = EpisodeSpec(soil, density, speed, depth, seed=seed, duration_s=duration)
    try:
        spec.resolve()
    except ValueError as err:
        assert any(f in str(err) for f in ("soil=", "relative_density_pct=", "target_speed_m_s=",
                                           "target_depth_m=", "duration_s=", "seed=")), str(err)
        return
    assert math.isfinite(spec.duration_s) and 0 <= spec.seed <= 2**63 - 1


def test_a_seed_beyond_64_bits_is_refused():
    """A 230-digit seed from /sim/command once went through into a bag name the file system refused."""
    assert EpisodeSpec("Clay", 50.0, 0.5, 0.1, seed=2**63 - 1).resolve()
    for seed in (2**63, 10**230):
        with pytest.raises(ValueError, match=r"seed=\d+ must be an integer in \[0, 2\*\*63 - 1\]"):
            EpisodeSpec("Clay", 50.0, 0.5, 0.1, seed=seed).resolve()


@FUZZ
@given(st.one_of(st.sampled_from(PACINGS), st.text(max_size=10)), st.one_of(any_float, st.integers(-10**6, 10**6)))
def test_pacing_checks_accept_in_range_or_name_the_parameter(pacing, rate):
    try:
        check_pacing(pacing, rate)
    except ValueError as err:
        assert "parameter pacing=" in str(err) or "parameter rate=" in str(err)
        return
    assert pacing in PACINGS and 0.01 <= rate <= 1000.0
