"""The pinn_estimator node over real DDS on loopback: live graph, replay, bad input, checkpoints.

Each test runs real processes (soil_launch, pinn_estimator, soil_bag_play) on its own
ROS_DOMAIN_ID and watches them from an in-process probe. Every wait is bounded.
"""
from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
import torch

from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_bag_tools.bag_io import find_episode_bags, read_episode, read_labelled_topic
from soil_msgs_py.params import WINDOW_SAMPLES
from pinn_estimator.checkpoint import DEFAULT_CHECKPOINT, load_model, save_checkpoint
from pinn_estimator.inference import episode_estimates
from pinn_estimator.model import EstimatorNet, ModelConfig
from pinn_estimator.online import INPUT_TOPICS, OnlineEstimator

from tests.ros_probe import call_service, BIN, NodeProc, RosProbe, loopback_env, next_domain_id, wait_until
from .test_online import SAMPLE, SCALE

pytestmark = pytest.mark.live

VALID = T.ESTIMATE_FIELDS.index("valid")


def estimates(probe: RosProbe) -> list[tuple[float, int, np.ndarray]]:
    """(receive time, stamp, values) of every /soil/estimate the probe got."""
    with probe.lock:
        got = list(probe.received[T.ESTIMATE.name])
    return [(t, *M.parse_labelled(m, T.ESTIMATE_FIELDS, T.ESTIMATE.name)) for t, m in got]


def replay_fast_and_stop(bag, ticks: int, tmp_path) -> tuple[list, str]:
    """(estimates, log) of a fresh estimator fed the bag's inputs 50 times faster than real time and
    stopped (SIGINT) the moment the player is done: whatever is still queued is its to finish. Its
    exit code must be 0, and ``ticks`` estimates must come."""
    domain = next_domain_id()
    with RosProbe(domain) as probe:
        probe.subscribe(T.ESTIMATE.name, T.ESTIMATE.msgtype)
        est = NodeProc("pinn_estimator", [], domain, tmp_path)
        try:
            # matched, not only discovered: a publisher the graph shows may not deliver yet, and on a
            # loaded machine the first replayed ticks' estimates were then lost
            wait_until(lambda: probe.matched_publishers(T.ESTIMATE.name) >= 1, 30, "the estimator's publisher matched")
            time.sleep(0.5)  # and the other way round, the estimator's writer to this reader
            player = subprocess.run(
                [str(BIN / "soil_bag_play"), str(bag), "--topics", *INPUT_TOPICS, "--wait-for-subscribers", "1",
                 "--wait-timeout", "30", "--rate", "50"], env=loopback_env(domain), capture_output=True, text=True,
                timeout=90)
            assert player.returncode == 0, player.stdout + player.stderr
        finally:
            code = est.stop(timeout=150.0)  # (its drain is bounded by DRAIN_ENDED_EPISODE_LIMIT_S)
        assert code == 0, est.output
        # (acknowledged before it exited; this probe's own thread may still be taking them)
        wait_until(lambda: len(estimates(probe)) >= ticks, 20,
                   f"estimates of the episode's {ticks} ticks (got {len(estimates(probe))}; estimator said "
                   f"{est.output[-2000:]}; player said {player.stdout[-1000:]}{player.stderr[-1000:]})")
        return estimates(probe), est.output


def test_live_estimates_at_60hz_equal_offline_and_replay(tmp_path):
    """sim + controller + estimator + recorder in real time: once the window is full an
    estimate arrives every tick, stamped with the tick it used, equal to the offline model on
    the recorded bag's windows; replaying the bag into a fresh estimator gives the same
    estimates within 1e-6, every one of them even when the replay runs 50 times faster than the
    estimator keeps up and the estimator is stopped the moment the player is done (the episode's
    queued last ticks are estimated before it stops)."""
    domain = next_domain_id()
    bags = tmp_path / "bags"
    with RosProbe(domain) as probe:
        probe.subscribe(T.ESTIMATE.name, T.ESTIMATE.msgtype)
        probe.subscribe(T.CLOCK.name, T.CLOCK.msgtype)  # so the simulator can wait for the probe
        launch = subprocess.run(
            [str(BIN / "soil_launch"), "--estimator", "--record", str(bags), "--domain-id", str(domain),
             "--wait-for", "/clock:1", "--sim-param", "settle_s:=1.0",
             "--sim-param", "duration_s:=3.0", "--sim-param", "soil:=Clay", "--timeout", "90"],
            env=loopback_env(domain), capture_output=True, text=True, timeout=120)
        assert launch.returncode == 0, launch.stdout[-3000:]
        live = estimates(probe)
    (bag,) = find_episode_bags(bags)
    ep = read_episode(bag)
    rec_stamps, rec_values = read_labelled_topic(bag, T.ESTIMATE.name, T.ESTIMATE_FIELDS)

    # Nothing waits for the estimator's publisher to be matched, neither by the recorder nor by
    # this probe (not launched with the graph): on a loaded machine either may find it after
    # the first ticks. From its first message on each got every tick, one estimate per tick of
    # the 60 Hz grid, valid from the 60th sample on; and the same values.
    stamps_live = [s for _, s, _ in live]
    for stamps in (rec_stamps.tolist(), stamps_live):
        assert stamps and stamps == ep.stamps_ns[len(ep) - len(stamps):].tolist()
        assert len(stamps) > len(ep) // 2, "less than half the episode's estimates arrived"
    first_valid = int(ep.stamps_ns[WINDOW_SAMPLES - 1])
    assert all((v[VALID] == 1.0) == (s >= first_valid) for _, s, v in live)
    good = [(t, s, v) for t, s, v in live if v[VALID] == 1.0]
    assert all(np.isfinite(v).all() for _, _, v in live)
    both = min(len(rec_stamps), len(stamps_live))
    np.testing.assert_array_equal(rec_values[len(rec_stamps) - both:], np.stack([v for _, _, v in live[len(live) - both:]]))
    # online == offline model on the same windows (float32 rounding of batch 1 vs batched)
    offline = dict(zip(*episode_estimates(load_model(DEFAULT_CHECKPOINT)[0], bag)))
    for _, s, v in good:
        np.testing.assert_array_less(np.abs(v - offline[s]) / SCALE, 1e-5)

    # replay: the recorded inputs, a fresh estimator, the same estimates
    replay, said = replay_fast_and_stop(bag, len(ep), tmp_path)
    assert [s for _, s, _ in replay] == ep.stamps_ns.tolist()  # this probe waited for the estimator: every tick
    diff = np.abs(np.stack([v for _, _, v in replay[len(ep) - len(rec_stamps):]]) - rec_values)
    assert diff.max() <= 1e-6, _where_they_differ(diff, rec_stamps, launch.stdout + said)
    assert "0 gaps, 0 out of order, 0 non-finite or implausible, 0 malformed" in said


def test_stopped_right_after_an_episode_ended_the_estimator_estimates_its_queued_last_ticks_first(tmp_path):
    """A lockstep simulator ends seconds of simulated time ahead of the estimator, and soil_launch
    stops the estimator as soon as the simulator is done (an outside tester's demo lost 139 of an
    episode's 600 estimates). Here a 20 s episode is replayed 50 times faster than real time and
    the estimator stopped the moment the player is done: it still publishes one estimate per tick,
    each the offline model's on the same window, and exits 0."""
    from soil_sim_node.batch import DatasetPlan, generate, grid_specs
    from soil_sim_node.effects import effects_for_mode

    specs = grid_specs(["Clay"], [40.0], [0.5], [0.15], 1, seed_base=7, duration_s=20.0)
    generate(DatasetPlan("default", tmp_path / "bags", specs, effects_for_mode("default")), workers=1, progress=False)
    (bag,) = find_episode_bags(tmp_path / "bags")
    ep = read_episode(bag)
    got, said = replay_fast_and_stop(bag, len(ep), tmp_path)
    print("drained after the stop" if "finishing the ended episode first" in said else "caught up before the stop")
    assert [s for _, s, _ in got] == ep.stamps_ns.tolist()
    offline = dict(zip(*episode_estimates(load_model(DEFAULT_CHECKPOINT)[0], bag)))
    good = [(s, v) for _, s, v in got if v[VALID] == 1.0]
    assert len(good) == len(ep) - WINDOW_SAMPLES + 1
    for s, v in good:
        np.testing.assert_array_less(np.abs(v - offline[s]) / SCALE, 1e-5)


def _where_they_differ(diff: np.ndarray, stamps: np.ndarray, logs: str) -> str:
    """A failure message that says which fields differ from which tick on, and what the
    nodes logged (a gap or a late episode event in the live run explains most)."""
    rows = np.flatnonzero(diff.max(axis=1) > 1e-6)
    fields = [T.ESTIMATE_FIELDS[j] for j in np.flatnonzero(diff.max(axis=0) > 1e-6)]
    noted = [line for line in logs.splitlines() if "WARN" in line or "episode" in line or "gaps" in line]
    return (f"replay differs from live by {diff.max()} in {fields} at {len(rows)} of {len(diff)} ticks, "
            f"from row {rows[0]} (stamp {int(stamps[rows[0]])} ns); logs:\n" + "\n".join(noted[-40:]))


def _build(ns, item):
    """A message from a neutral (topic, stamp, values, labels) item, for rosbags or rclpy."""
    topic, stamp, values, labels = item
    if labels is not None:
        return M.make_labelled(ns, stamp, labels, values)
    return M.build_message(ns, topic, stamp, values)


def test_bad_input_is_logged_never_published_as_nan_and_the_node_survives(tmp_path):
    """NaN/inf fields, a dropped tick, out-of-order stamps and wrong-shaped arrays over DDS:
    the node publishes exactly what the core computes for the same message sequence, no
    NaN, logs each kind of problem, and keeps estimating."""
    ep = read_episode(SAMPLE)
    rows = {t: M.topic_rows(ep, t) for t in INPUT_TOPICS}
    stamps = ep.stamps_ns.tolist()

    def tick(i, stamp=None):
        return [(t, stamps[i] if stamp is None else stamp, rows[t][i].copy(), None) for t in INPUT_TOPICS]

    items = []
    for i in range(330):
        msgs = tick(i)
        if i == 80:  # NaN in Θ_k (d)
            msgs[INPUT_TOPICS.index(T.KNOWN.name)][2][T.KNOWN.labels.index("d")] = np.nan
        if i == 150:  # a dropped tick
            continue
        if i == 220:  # an array of the wrong shape for the blade command
            msgs[INPUT_TOPICS.index(T.BLADE_CMD.name)] = (T.BLADE_CMD.name, stamps[i], [0.0, 0.0, 1.0],
                                                          ("u_zr", "u_za", "extra"))
        items += msgs
        if i == 260:  # a stale, out-of-order stamp
            items += tick(255)[:1]
    # What the core publishes for this sequence (one torch thread, like the node: same rounding)
    torch.set_num_threads(1)
    expected = []
    core = OnlineEstimator(load_model(DEFAULT_CHECKPOINT)[0], expected.append)
    for item in items:
        core.add(item[0], _build(M.TYPESTORE, item))
    n_valid = sum(e.valid for e in expected)
    # windows restart after ticks 80 (NaN), 150 (dropped), 220 (malformed) and 260 (stale message)
    assert n_valid == (80 - 59) + (150 - 140) + (220 - 210) + (330 - 320), n_valid

    classes = M.ros_message_classes()
    domain = next_domain_id()
    with RosProbe(domain) as probe:
        probe.subscribe(T.ESTIMATE.name, T.ESTIMATE.msgtype)
        probe.subscribe(T.ESTIMATED_FORCE.name, T.ESTIMATED_FORCE.msgtype)
        node = NodeProc("pinn_estimator", [], domain, tmp_path)
        try:
            pubs = {t: probe.publisher(t, T.TOPICS_BY_NAME[t].msgtype) for t in INPUT_TOPICS}
            for topic, pub in pubs.items():
                wait_until(lambda p=pub: p.get_subscription_count() >= 1, 30, f"estimator subscribed to {topic}")
            time.sleep(0.3)
            for item in items:
                pubs[item[0]].publish(_build(classes, item))
                if item[0] == INPUT_TOPICS[-1]:
                    # at the graph's own 60 Hz: at twice it, a node slowed by the other worker's test fell more
                    # than its readers' 2 s of history behind and lost ticks (a suite run on 2 cores)
                    time.sleep(1 / 60)
            wait_until(lambda: len(estimates(probe)) >= len(expected), 20, "all estimates")
            time.sleep(0.3)
            got = estimates(probe)
            assert node.proc.poll() is None, node.output
        finally:
            code = node.stop()
        forces = probe.messages(T.ESTIMATED_FORCE.name)
    assert code == 0, node.output
    assert [s for _, s, _ in got] == [e.stamp_ns for e in expected]
    for (_, _, v), e in zip(got, expected):
        np.testing.assert_array_equal(v, e.values)
        assert np.isfinite(v).all()
    assert len(forces) == n_valid
    log = node.output
    for needle in ("field d=nan", "tick(s) missing", "(out of order); window reset", "label mismatch"):
        assert needle in log, f"no warning with {needle!r} in\n{log}"
    assert "1 out of order, 1 non-finite or implausible, 1 malformed, 0 duplicates, 0 evicted, 0 restarts" in log


def test_bad_checkpoint_exits_2_and_a_bad_runtime_swap_is_refused(tmp_path):
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a checkpoint at all")
    domain = next_domain_id()
    bad = NodeProc("pinn_estimator", ["--ros-args", "-p", f"checkpoint:={corrupt}"], domain, tmp_path)
    assert bad.wait(60) == 2
    assert "checkpoint refused" in bad.output and "not a readable torch checkpoint" in bad.output
    bad.stop()

    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    with RosProbe(domain) as probe:
        node = NodeProc("pinn_estimator", [], domain, tmp_path)
        try:
            client = AsyncParameterClient(probe.node, "pinn_estimator")
            assert client.wait_for_services(timeout_sec=30.0)

            def set_param(name, value):
                # the guard is for hangs only: a node still loading torch beside a busy core answered in > 10 s
                answer = call_service(lambda: client.set_parameters([Parameter(name, value=value)]), f"set {name}",
                                      timeout=90.0, resend_after_s=15.0)
                return answer.results[0]

            refused = set_param("checkpoint", str(corrupt))
            assert not refused.successful and "not a readable torch checkpoint" in refused.reason
            short = save_checkpoint(tmp_path / "w30.pt", EstimatorNet(ModelConfig(window=30), torch.zeros(9), torch.ones(9)),
                                    train_config={}, dataset={}, split={}, metrics={}, history={})
            refused = set_param("checkpoint", str(short))  # loads, but cannot run on 60-sample windows
            assert not refused.successful and "window=30" in refused.reason
            assert not set_param("stride", 0).successful
            refused = set_param("inputs_wait_s", -1.0)  # read once, at start: it was taken unchecked
            assert not refused.successful and "['inputs_wait_s'] can only be set at start-up" in refused.reason
            fee_model = DEFAULT_CHECKPOINT.with_name("pinn_fee.pt")
            assert set_param("checkpoint", str(fee_model)).successful
            wait_until(lambda: f"model now {fee_model}" in node.output, 60, "model swap logged")
            # the posterior's calibration, the checkpoint's world's, follows the new model's world
            wait_until(lambda: "fusion_fee.json (the checkpoint's world)" in node.output, 10, "the fee world's calibration")
        finally:
            assert node.stop() == 0, node.output


def test_the_estimator_joins_sim_status_only_once_every_input_has_a_publisher(tmp_path):
    """A simulator holds tick 0 until its /sim/status readers have matched: the estimator's
    must not count before the estimator can hear the whole tick (the controller's commands
    included), and not wait for ever for an input nobody publishes."""
    from soil_msgs_py import graph as G

    domain = next_domain_id()
    with RosProbe(domain) as probe:
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        waiting = NodeProc("pinn_estimator", ["--ros-args", "-p", "inputs_wait_s:=600.0"], domain, tmp_path)
        try:
            pubs = [probe.publisher(t, T.TOPICS_BY_NAME[t].msgtype) for t in INPUT_TOPICS[:-1]]
            wait_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs), 60, "the estimator's inputs")
            time.sleep(1.0)
            assert status.get_subscription_count() == 0  # one input still has no publisher
            pubs.append(probe.publisher(INPUT_TOPICS[-1], T.TOPICS_BY_NAME[INPUT_TOPICS[-1]].msgtype))
            wait_until(lambda: status.get_subscription_count() >= 1, 30, "the estimator's /sim/status reader")
        finally:
            assert waiting.stop() == 0, waiting.output
    domain = next_domain_id()
    with RosProbe(domain) as probe:
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        alone = NodeProc("pinn_estimator", ["--ros-args", "-p", "inputs_wait_s:=1.0"], domain, tmp_path)
        try:
            wait_until(lambda: status.get_subscription_count() >= 1, 60, "the /sim/status reader after inputs_wait_s")
        finally:
            alone.stop()
        assert "without a publisher of" in alone.output and T.BLADE_CMD.name in alone.output, alone.output


def test_a_fee_checkpoint_takes_the_fee_worlds_calibration_and_a_default_world_episode_is_said(tmp_path):
    """Without fusion_config the soil posterior takes the shipped calibration of the checkpoint's
    training world (a fee model read through the default world's error laws fused a clay 7° off),
    and an episode of another world is said once, naming the config to give."""
    from std_msgs.msg import String

    from pinn_estimator.fusion_calibration import config_path, load_calibrated
    from soil_msgs_py import graph as G
    from soil_msgs_py.episode import EpisodeMeta

    fee_ckpt = DEFAULT_CHECKPOINT.with_name("pinn_fee.pt")
    domain = next_domain_id()
    with RosProbe(domain) as probe:
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        node = NodeProc("pinn_estimator", ["--ros-args", "-p", f"checkpoint:={fee_ckpt}", "-p", "inputs_wait_s:=0.0"],
                        domain, tmp_path)
        try:
            wait_until(lambda: status.get_subscription_count() >= 1, 60, "the estimator's /sim/status reader")
            time.sleep(0.3)
            for episode, world in enumerate(("fee", "default", "default")):
                meta = EpisodeMeta("Clay", 50.0, world, 1, 0.5, 0.15, 5.0)
                event = G.EpisodeEvent(G.EVENT_EPISODE_START, episode, f"{world}_{episode}", meta, 10**9 * episode)
                status.publish(String(data=event.to_json()))
            wait_until(lambda: node.output.count("new window") >= 3, 30, "the three episode starts")
        finally:
            node.stop()
        out = node.output
        assert f"soil posterior {config_path('fee')} (the checkpoint's world)" in out, out[-3000:]
        # the start line gives the forecast law /soil/estimate publishes (it gave only the evidence law's rel)
        law = load_calibrated("fee")
        assert (f"forecast law x {law.forecast_abs_std_n[0]:g} N + {law.forecast_rel_std[0]:g}·|ΔF|, "
                f"z {law.forecast_abs_std_n[1]:g} N + {law.forecast_rel_std[1]:g}·|ΔF|") in out, out[-3000:]
        assert out.count("is the default world's") == 1 and str(config_path("default")) in out, out[-3000:]
        assert f"its shipped checkpoint:={DEFAULT_CHECKPOINT}" in out, out[-3000:]  # the model to give, by name
        assert "fee_0 is the" not in out
