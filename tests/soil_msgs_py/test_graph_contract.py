"""The graph contract without DDS: /sim/status and /sim/command JSON, the command gate, plans."""
from __future__ import annotations

import dataclasses
import json
import math

import pytest

from soil_msgs_py import graph as G
from soil_msgs_py.episode import EpisodeMeta
from soil_bringup.launch import build_nodes, parse_args
from soil_sim_node.live import COMMAND_LIMITS, CommandGate, episode_plan
from soil_sim_node.pacing import TickTiming
from soil_sim_node.simulator import EpisodeSpec

META = EpisodeMeta("Clay", 40.0, "fee", 3, 0.5, 0.1, 2.0, source="soil_sim_node")


def test_episode_events_round_trip():
    start = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, META.name, META, 0, planned_ticks=120)
    end = G.EpisodeEvent(G.EVENT_EPISODE_END, 0, META.name, META, 0, 120, last_stamp_ns=1983333333,
                         ticks=120, reason="completed", stats={"late_commands": 0})
    assert G.EpisodeEvent.from_json(start.to_json()) == start
    assert G.EpisodeEvent.from_json(end.to_json()) == end
    launched = dataclasses.replace(end, graph="launch-123-ab12cd34")  # (a launch's id of its graph)
    assert G.EpisodeEvent.from_json(launched.to_json()) == launched and '"graph"' not in end.to_json()


@pytest.mark.parametrize("change, needle", [
    ({"event": "episode_middle"}, "event='episode_middle'"),
    ({"first_stamp_ns": -5}, "first_stamp_ns=-5"),
    ({"episode": 1.5}, "episode=1.5"),
    ({"reason": "bored"}, "reason='bored'"),
    ({"name": "a/b"}, "name='a/b'"),
    ({"meta": {**json.loads(META.to_json()), "world_mode": "moon"}}, "world_mode='moon'"),
    ({"meta": {k: v for k, v in json.loads(META.to_json()).items() if k != "seed"}}, "bad meta: .*seed"),
    ({"meta": {**json.loads(META.to_json()), "relative_density_pct": "dense"}}, "relative_density_pct='dense'"),
    ({"stats": [1, 2]}, "stats=[1, 2]"),
    ({"graph": 7}, "graph=7 must be a string"),
    ({"graph": "a/b"}, "graph='a/b' must be a string of at most 64 letters"),
])
def test_bad_status_events_are_named(change, needle):
    end = G.EpisodeEvent(G.EVENT_EPISODE_END, 0, META.name, META, 0, 120, 1, 120, "completed")
    data = {**json.loads(end.to_json()), **change}
    with pytest.raises(ValueError, match=needle.replace("[", r"\[").replace("]", r"\]")):
        G.EpisodeEvent.from_json(json.dumps(data))


@pytest.mark.parametrize("world", ["unknown", "", None])
def test_a_machine_bags_episode_event_is_taken(world):
    """A machine's bag replayed frames its episode like a simulated one: its world is not a
    simulator's (the bag readers take it), and a recorder that refused its events recorded nothing."""
    meta = dataclasses.replace(META, world_mode=world)
    start = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, "machine_run", meta, 0, planned_ticks=120)
    assert G.EpisodeEvent.from_json(start.to_json()).meta.world_mode == world


@pytest.mark.parametrize("text, needle", [
    ("[1, 2]", "expected a JSON object"),
    ('{"action": "fly"}', "action='fly'"),
    ('{"action": "reset", "soil": "Clay"}', "takes no fields"),
    ('{"action": "start", "colour": "red"}', "unknown field"),
    ('{"action": "start", "seed": -1}', "seed=-1"),
    ('{"action": "start", "duration_s": NaN}', "duration_s=nan"),
    ('{"action": "start", "soil": 3}', "soil=3"),
    # an outside tester's: the last of two actions was taken (a shutdown), and a bool seed was "no finite number"
    ('{"action": "start", "action": "shutdown"}', "field 'action' is given twice"),
    ('{"action": "start", "seed": true}', r"seed=True must be an integer in \[0, 2\*\*63 - 1\]"),
])
def test_bad_sim_commands_are_named(text, needle):
    with pytest.raises(ValueError, match=needle):
        G.SimCommand.from_json(text)


def test_sim_command_start_overrides():
    cmd = G.SimCommand.from_json('{"action": "start", "soil": "Sand", "seed": 4}')
    assert cmd.action == "start" and cmd.overrides == {"soil": "Sand", "seed": 4}


def test_command_gate_accepts_only_the_answered_tick_and_sanitises():
    gate = CommandGate()
    assert gate.offer("/chassis/cmd_vel", 0, [0.5])[0][0] == "/chassis/cmd_vel:stamp:idle"
    gate.expect(100)
    assert gate.offer("/chassis/cmd_vel", 99, [0.5])[0][0].endswith("stamp:stale")
    assert gate.offer("/chassis/cmd_vel", 101, [0.5])[0][0].endswith("stamp:future")
    assert gate.offer("/chassis/cmd_vel", 100, [0.4]) == [] and not gate.complete
    assert gate.offer("/chassis/cmd_vel", 100, [0.3])[0][0].endswith("stamp:repeated")
    (kind, text), = gate.offer("/blade/cmd", 100, [math.nan, -0.1])
    assert kind == "/blade/cmd:u_zr:nan" and "holding 0.0" in text and gate.complete
    assert gate.take() == (0.0, -0.1, 0.4)
    gate.expect(200)
    kinds = [k for k, _ in gate.offer("/blade/cmd", 200, [7.0, math.inf])]
    assert kinds == ["/blade/cmd:u_zr:out_of_range", "/blade/cmd:u_za:inf"]
    assert gate.take() == (COMMAND_LIMITS["u_zr"][1], -0.1, 0.4)  # u_x held: its command did not come
    assert gate.rejected == 4 and gate.sanitised == 2


def test_episode_plan_is_soils_by_densities_by_repeats_with_consecutive_seeds():
    base = EpisodeSpec("Loam", 60.0, 0.5, 0.2, seed=10, duration_s=3.0)
    plan = episode_plan(base, ["Clay", "Sand"], [0.0, 100.0], 2)
    assert [(s.soil, s.relative_density_pct, s.seed) for s in plan] == [
        ("Clay", 0.0, 10), ("Clay", 0.0, 11), ("Clay", 100.0, 12), ("Clay", 100.0, 13),
        ("Sand", 0.0, 14), ("Sand", 0.0, 15), ("Sand", 100.0, 16), ("Sand", 100.0, 17)]
    assert episode_plan(base, [], [], 1) == [base]
    assert episode_plan(base, [], [], 0) == []
    last = dataclasses.replace(base, seed=2**63 - 1)  # the last seed there is: one episode, not two
    assert [s.seed for s in episode_plan(last, [], [], 1)] == [2**63 - 1]
    with pytest.raises(ValueError, match=r"seed=9223372036854775807 with 2 episodes in the plan reaches seed "
                                         r"9223372036854775808, beyond 2\*\*63 - 1"):
        episode_plan(last, [], [], 2)


def test_tick_timing_summary():
    t = TickTiming(nominal_period_s=0.01)
    for k in range(5):
        t.published(k * 0.011)
        t.answered(k * 0.011 + 0.001)
    s = t.summary()
    assert s["period"]["p50_ms"] == pytest.approx(11.0) and s["jitter"]["max_ms"] == pytest.approx(1.0)
    assert s["loop_latency"]["n"] == 5 and s["loop_latency"]["p99_ms"] == pytest.approx(1.0)


def test_launcher_tells_the_simulator_whom_to_wait_for(tmp_path):
    nodes = build_nodes(parse_args(["--record", str(tmp_path), "--pacing", "lockstep", "--sim-param", "soil:=Sand"]))
    assert [n.name for n in nodes] == ["recorder", "controller", "sim"]
    sim = nodes[-1].argv
    wait = next(a for a in sim if a.startswith("wait_for:="))
    # /blade/force: the recorder's reader and the controller's (which joins it with its force lift on)
    assert "'/chassis/twist:2'" in wait and "'/blade/force:2'" in wait and "'/sim/status:2'" in wait
    assert "'/chassis/cmd_vel:1'" in wait and "pacing:=lockstep" in sim and "soil:=Sand" in sim
    with pytest.raises(SystemExit):
        parse_args(["--domain-id", "999"])


@pytest.mark.parametrize("pkg, node_module, node_name", [("soil_sim_node", "soil_sim_node.node", "soil_sim_node"),
                                                          ("anti_stall_controller", "anti_stall_controller.node",
                                                           "anti_stall_controller"),
                                                          ("pinn_estimator", "pinn_estimator.node", "pinn_estimator"),
                                                          ("soil_planner", "soil_planner.node", "soil_planner")])
def test_shipped_params_yaml_lists_every_parameter_with_its_default(pkg, node_module, node_name):
    """src/<pkg>/config/<node>.yaml is the documented default set: same names, same values as the node."""
    import importlib
    from pathlib import Path

    import yaml

    params = importlib.import_module(node_module).PARAMETERS
    path = Path(__file__).resolve().parents[2] / "src" / pkg / "config" / f"{node_name}.yaml"
    data = yaml.safe_load(path.read_text())[node_name]["ros__parameters"]
    assert list(data) == list(params)
    assert {k: v for k, v in data.items()} == {k: spec[0] for k, spec in params.items()}


def test_a_point_cloud_round_trips_and_a_foreign_layout_is_refused():
    from soil_msgs_py import messages as M
    from soil_msgs_py import topics as T
    import numpy as np
    import pytest

    rows = np.arange(3 * len(T.MAP_FIELDS), dtype=float).reshape(3, -1) / 7
    msg = M.make_point_cloud(M.TYPESTORE, 1_500_000_000, T.MAP_FIELDS, rows)
    stamp, back = M.parse_point_cloud(msg, T.MAP_FIELDS, T.SOIL_MAP.name)
    assert stamp == 1_500_000_000 and msg.header.frame_id == T.WORLD_FRAME and msg.width == 3
    np.testing.assert_allclose(back, rows, rtol=1e-6)
    raw = M.TYPESTORE.serialize_cdr(msg, T.SOIL_MAP.msgtype)  # what a bag holds
    assert M.parse_point_cloud(M.TYPESTORE.deserialize_cdr(raw, T.SOIL_MAP.msgtype), T.MAP_FIELDS)[0] == stamp
    with pytest.raises(ValueError, match="/soil/map: point cloud layout"):
        M.parse_point_cloud(msg, T.MAP_FIELDS[:-1], T.SOIL_MAP.name)
