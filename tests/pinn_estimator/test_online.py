"""Online estimation core (pinn_estimator.online): real model, real messages, no DDS.

Every test feeds the messages a live estimator would receive (built with the same
``messages.build_message`` the nodes use, from a recorded sample bag) and checks what it
would publish: stamps, validity, values against the offline model on the same windows.
"""
from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
import torch

from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.episode import Episode
from soil_bag_tools.bag_io import read_episode
from soil_msgs_py.params import WINDOW_SAMPLES
from soil_physics.travel import distance_in_soil_of_known
from pinn_estimator.checkpoint import DEFAULT_CHECKPOINT, load_model, save_checkpoint
from pinn_estimator.fusion import fused_track
from pinn_estimator.fusion_calibration import DEFAULT_WORLD, load_calibrated
from pinn_estimator.inference import episode_estimates
from pinn_estimator.model import EstimatorNet, ModelConfig
from pinn_estimator.node import load_estimator_model
from pinn_estimator.online import FUSED, INPUT_TOPICS, OnlineEstimator, SampleAssembler

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "samples" / "default_loam_id060_v0.50_d0.200_s7"
N_TICKS = 200
VALID = T.ESTIMATE_FIELDS.index("valid")
FUSED_VALID = T.ESTIMATE_FIELDS.index("fused_valid")
FILL = T.ESTIMATE_FIELDS.index("window_samples")


@pytest.fixture(scope="module")
def episode():
    return read_episode(SAMPLE)


@pytest.fixture(scope="module")
def model():
    torch.set_num_threads(1)
    return load_model(DEFAULT_CHECKPOINT)[0]


@pytest.fixture(scope="module")
def offline(model):
    """The offline pipeline's (load_dataset -> predict, batched) /soil/estimate values for the
    window ending at every tick >= 59 of the sample episode."""
    return dict(zip(*episode_estimates(model, SAMPLE)))


def tick_messages(ep, i: int, stamp: int | None = None) -> list[tuple[str, object]]:
    """The input messages of tick ``i`` (one per ``INPUT_TOPICS``, optionally re-stamped)."""
    s = int(ep.stamps_ns[i]) if stamp is None else stamp
    return [(t, M.build_message(M.TYPESTORE, t, s, M.topic_rows(ep, t)[i])) for t in INPUT_TOPICS]


def run(model, messages, **kw):
    out = []
    est = OnlineEstimator(model, out.append, **kw)
    for topic, msg in messages:
        est.add(topic, msg)
    return est, out


def in_order(ep, ticks):
    return [m for i in ticks for m in tick_messages(ep, i)]


# Typical size of each field (rad, Pa, rad, rad, m, 6 forces N, flag, count; then the fused
# means and stds (rad, Pa, rad, rad), 3 correlations, model error (N, N, 1, 1, 1, 1), flag, count):
# float32 rounding differs between batch sizes by ~1e-7 of the network's output scale, not of
# the value (the fused fields are float64 and the same ops online and offline: equal).
SCALE = np.array([1.0, 1e4, 1.0, 1.0, 0.1] + [2e4] * 6 + [1.0, 60.0]
                 + [1.0, 1e4, 1.0, 1.0] * 2 + [1.0] * 3 + [1e3, 1e3, 1.0, 1.0, 1.0, 1.0, 1.0, 100.0])
assert len(SCALE) == len(T.ESTIMATE_FIELDS)


def assert_matches_offline(estimates, offline, rel=1e-5, fields=slice(None)):
    """Online (batch 1) equals the offline model (batched) up to float32 rounding (``fields``:
    which; after a gap only the PINN's: the fused posterior's stretches are the gap-free
    track's no more)."""
    assert estimates, "no valid estimate"
    for e in estimates:
        np.testing.assert_array_less(np.abs(e.values - offline[e.stamp_ns])[fields] / SCALE[fields], rel)


PINN_FIELDS = slice(0, FUSED.start)
STRETCHES = T.ESTIMATE_FIELDS.index("fused_stretches")


def assert_gap_keeps_the_posterior(out, gap_stamp):
    """A gap drops the stretch in progress, not what the posterior learnt."""
    before = [e.values[STRETCHES] for e in out if e.stamp_ns < gap_stamp]
    after = [e.values[STRETCHES] for e in out if e.stamp_ns > gap_stamp]
    assert before[-1] >= 2 and after[0] == before[-1] and after[-1] > before[-1]


def valid(out):
    return [e for e in out if e.valid]


def assert_never_nan(out):
    assert all(np.isfinite(e.values).all() for e in out)
    for e in out:
        if not e.valid:
            assert not e.values[:VALID].any(), "an invalid estimate carries no numbers"


# ---------------------------------------------------------------------------------------- normal

def test_every_full_window_is_estimated_stamped_with_its_newest_sample(episode, model, offline):
    est, out = run(model, in_order(episode, range(N_TICKS)))
    assert [e.stamp_ns for e in out] == episode.stamps_ns[:N_TICKS].tolist(), "one message per tick"
    good = valid(out)
    assert [e.stamp_ns for e in good] == episode.stamps_ns[WINDOW_SAMPLES - 1 : N_TICKS].tolist()
    assert [e.values[FILL] for e in out[:WINDOW_SAMPLES]] == list(range(1, WINDOW_SAMPLES + 1))
    assert_matches_offline(good, offline)
    assert_never_nan(out)
    c = est.counters
    assert (c.samples, c.estimates, c.invalid, c.gaps) == (N_TICKS, N_TICKS - 59, 59, 0)


def test_arrival_order_within_the_reorder_horizon_does_not_matter(episode, model):
    """DDS orders each topic, not topics against each other: shuffling across two ticks
    gives exactly the same estimates as in-order arrival."""
    msgs = in_order(episode, range(120))
    rng = random.Random(3)
    shuffled = []
    two = 2 * len(INPUT_TOPICS)
    for k in range(0, len(msgs), two):  # two ticks at a time, topics mixed, per-topic order kept
        chunk = msgs[k : k + two]
        rng.shuffle(chunk)
        per_topic = {}
        for t, m in chunk:
            per_topic.setdefault(t, []).append(m)
        for t in per_topic:
            per_topic[t].sort(key=lambda m: M.parse_message(t, m)[0])
        shuffled += [(t, per_topic[t].pop(0)) for t, _ in chunk]
    _, a = run(model, msgs)
    _, b = run(model, shuffled)
    assert [(e.stamp_ns, e.values.tolist()) for e in valid(a)] == [(e.stamp_ns, e.values.tolist()) for e in valid(b)]


def test_stride_estimates_every_nth_tick(episode, model):
    _, out = run(model, in_order(episode, range(N_TICKS)), stride=4)
    stamps = episode.stamps_ns[:N_TICKS]
    assert [e.stamp_ns for e in out] == stamps[::4].tolist()
    assert [e.stamp_ns for e in valid(out)] == [s for s in stamps[::4].tolist() if s >= stamps[59]]
    with pytest.raises(ValueError, match="stride=0"):
        OnlineEstimator(model, print, stride=0)


# ---------------------------------------------------------------------------------------- bad input

def test_a_dropped_tick_resets_the_window_and_nothing_is_estimated_across_it(episode, model, offline):
    est, out = run(model, in_order(episode, [i for i in range(N_TICKS) if i != 100]))
    stamps = [e.stamp_ns for e in valid(out)]
    s = episode.stamps_ns
    assert stamps == s[59:100].tolist() + s[160:N_TICKS].tolist(), "first estimate after the gap needs 60 new samples"
    assert est.counters.gaps == 1
    assert [e.values[FILL] for e in out if e.stamp_ns == s[101]] == [1.0]
    assert_matches_offline(valid(out), offline, fields=PINN_FIELDS)  # windows ending at >= 160 hold only ticks 101..
    assert_gap_keeps_the_posterior(out, s[100])
    assert_never_nan(out)


def test_one_missing_message_makes_its_tick_missing(episode, model):
    msgs = [(t, m) for t, m in in_order(episode, range(N_TICKS))
            if not (t == T.BLADE_CMD.name and M.parse_message(t, m)[0] == episode.stamps_ns[100])]
    est, out = run(model, msgs, reorder_ticks=3)
    s = episode.stamps_ns
    assert [e.stamp_ns for e in valid(out)] == s[59:100].tolist() + s[160:N_TICKS].tolist()
    assert est.counters.gaps == 1
    assert_never_nan(out)


def test_nan_or_inf_field_drops_the_tick_and_is_never_published(episode, model):
    msgs = in_order(episode, range(N_TICKS))
    rows = M.topic_rows(episode, T.KNOWN.name)[100].copy()
    rows[T.KNOWN.labels.index("q")] = np.nan
    bad_known = M.build_message(M.TYPESTORE, T.KNOWN.name, int(episode.stamps_ns[100]), rows)
    twist = M.topic_rows(episode, T.BLADE_TWIST.name)[150].copy()
    twist[0] = np.inf  # v_x^b: not a model input, still a broken message
    bad_twist = M.build_message(M.TYPESTORE, T.BLADE_TWIST.name, int(episode.stamps_ns[150]), twist)
    msgs = [(t, bad_known if (t == T.KNOWN.name and M.parse_message(t, m)[0] == episode.stamps_ns[100]) else
             bad_twist if (t == T.BLADE_TWIST.name and M.parse_message(t, m)[0] == episode.stamps_ns[150]) else m)
            for t, m in msgs]
    warnings = []
    est, out = run(model, msgs, warn=lambda kind, text: warnings.append(text))
    assert est.counters.non_finite == 2
    assert any("field q=nan" in w for w in warnings) and any("field v_x_b=inf" in w for w in warnings)
    s = episode.stamps_ns
    assert [e.stamp_ns for e in valid(out)] == s[59:100].tolist(), "each bad tick costs a full window"
    assert_never_nan(out)


def test_an_implausible_finite_field_drops_the_tick_like_a_nan(episode, model):
    """A blade pose at z = −1e300 m (an outside tester's, three ticks) had passed as finite: the
    model's output went non-finite for a window, and the fused posterior took the samples and
    stayed 8° off, with tighter intervals, for the rest of the episode; a 1e30 N force passed
    without a word. Such a tick is dropped at the input, named, as a NaN is."""
    msgs = in_order(episode, range(N_TICKS))
    pose = M.topic_rows(episode, T.BLADE_POSE.name)[100].copy()
    pose[1] = -1e300
    bad_pose = M.build_message(M.TYPESTORE, T.BLADE_POSE.name, int(episode.stamps_ns[100]), pose)
    msgs = [(t, bad_pose if (t == T.BLADE_POSE.name and M.parse_message(t, m)[0] == episode.stamps_ns[100]) else m)
            for t, m in msgs]
    warnings = []
    est, out = run(model, msgs, warn=lambda kind, text: warnings.append(text))
    assert est.counters.non_finite == 1 and est.counters.model_non_finite == 0
    assert any("=-1e+300" in w and "beyond ±1e+09" in w for w in warnings), warnings
    s = episode.stamps_ns
    assert [e.stamp_ns for e in valid(out)] == s[59:100].tolist() + s[160:N_TICKS].tolist()
    assert_never_nan(out)
    # a subnormal is a value at rest (a quantity decaying to 0), not garbage: its tick is kept
    pose[1] = 5e-324
    tiny = M.build_message(M.TYPESTORE, T.BLADE_POSE.name, int(episode.stamps_ns[100]), pose)
    est, out = run(model, [(t, tiny if m is bad_pose else m) for t, m in msgs])
    assert est.counters.non_finite == 0 and [e.stamp_ns for e in valid(out)] == s[59:N_TICKS].tolist()


def test_out_of_order_stamp_invalidates_the_window(episode, model, offline):
    msgs = in_order(episode, range(0, 101)) + tick_messages(episode, 97)[:1] + in_order(episode, range(101, N_TICKS))
    warnings = []
    est, out = run(model, msgs, warn=lambda kind, text: warnings.append(text))
    assert est.counters.out_of_order == 1 and any("out of order" in w for w in warnings)
    s = episode.stamps_ns
    assert [e.stamp_ns for e in valid(out)] == s[59:101].tolist() + s[160:N_TICKS].tolist()
    assert_matches_offline(valid(out), offline, fields=PINN_FIELDS)
    assert_gap_keeps_the_posterior(out, s[100])


def test_a_few_ticks_stale_is_out_of_order_not_a_restart(episode, model):
    for back in (4, 10, 59):
        msgs = in_order(episode, range(0, 101)) + tick_messages(episode, 100 - back)[:1] + in_order(episode, range(101, N_TICKS))
        est, out = run(model, msgs)
        assert (est.counters.out_of_order, est.counters.restarts) == (1, 0), back
        assert [e.stamp_ns for e in valid(out)][-1] == episode.stamps_ns[N_TICKS - 1]


def test_bogus_future_stamps_do_not_stall_estimation(episode, model):
    """A publisher with wrong (e.g. wall-clock) stamps on one topic: refused as far ahead (or, before
    the first tick left, aged out of the pending ticks), and real ticks keep being estimated."""
    msgs = []
    for i in range(N_TICKS):
        msgs += tick_messages(episode, i)
        bogus = M.build_message(M.TYPESTORE, T.CMD_VEL.name, 10**18 + i * 10**9, [0.5])
        msgs.append((T.CMD_VEL.name, bogus))
    est, out = run(model, msgs)
    assert [e.stamp_ns for e in valid(out)] == episode.stamps_ns[59:N_TICKS].tolist()
    assert est.counters.evicted + est.counters.out_of_order == N_TICKS and est.counters.restarts == 0
    assert len(est.assembler.joiner) <= 2 * 60


def test_stride_phase_restarts_with_each_episode(episode, model):
    """With stride > 1 the estimated ticks of an episode do not depend on how the previous one
    ended: live and replay (which starts fresh) estimate the same ticks."""
    out = []
    est = OnlineEstimator(model, out.append, stride=3)
    for t, m in in_order(episode, range(101)):  # 101 ticks: phase ends mid-stride
        est.add(t, m)
    est.end_episode(int(episode.stamps_ns[100]))
    base = int(episode.stamps_ns[100]) + int(episode.stamps_ns[1])
    for i in range(100):
        for t, m in tick_messages(episode, i, base + int(episode.stamps_ns[i])):
            est.add(t, m)
    second = [e.stamp_ns - base for e in out if e.stamp_ns >= base]
    assert second == episode.stamps_ns[:100:3].tolist()


def test_wrong_shape_array_is_malformed_and_its_tick_missing(episode, model):
    msgs = in_order(episode, range(N_TICKS))
    stamp = int(episode.stamps_ns[80])
    short = M.make_labelled(M.TYPESTORE, stamp, ("u_zr",), [0.1])  # one value, other label
    wrong_len = M.build_message(M.TYPESTORE, T.BLADE_CMD.name, stamp, [0.1, 0.2])
    wrong_len.data = wrong_len.data[:3]  # label says 4 entries, data has 3
    msgs = [(t, short if (t == T.BLADE_CMD.name and M.parse_message(t, m)[0] == stamp) else m) for t, m in msgs]
    msgs.insert(5, (T.BLADE_CMD.name, wrong_len))
    est, out = run(model, msgs)
    assert est.counters.malformed == 2
    s = episode.stamps_ns
    assert [e.stamp_ns for e in valid(out)] == s[59:80].tolist() + s[140:N_TICKS].tolist()
    assert_never_nan(out)


def test_a_topic_that_never_comes_holds_bounded_memory(episode, model):
    msgs = [(t, m) for t, m in in_order(episode, range(400)) if t != T.CMD_VEL.name]
    est, out = run(model, msgs)
    assert out == [] and len(est.assembler.joiner) <= 2 * 60


def test_non_finite_model_output_is_published_invalid(episode, model):
    broken, _ = load_model(DEFAULT_CHECKPOINT)
    with torch.no_grad():
        broken.head.bias[5] = float("nan")  # the F_r output
    est, out = run(broken, in_order(episode, range(70)))
    assert len(out) == 70 and not valid(out) and est.counters.model_non_finite == 11
    assert_never_nan(out)


def test_a_model_whose_force_is_far_beyond_the_machines_limits_is_published_invalid(episode, model):
    """A model whose training diverged (``pinn_train --lr 1``: F̂ 185-280 times the force limits)
    ran live without a word, and the planner anchored its cut to it (an outside tester's). An F̂
    beyond IMPLAUSIBLE_ESTIMATE_FACTOR times the limits is published invalid, counted and warned;
    the soil fused along the path, from the measured force, still goes out with it."""
    from pinn_estimator.online import IMPLAUSIBLE_ESTIMATE_FACTOR

    broken, _ = load_model(DEFAULT_CHECKPOINT)
    with torch.no_grad():
        broken.head.bias[5] += 1e4  # the F_r output, far beyond any force
    said = []
    est, out = run(broken, in_order(episode, range(200)), warn=lambda key, text: said.append((key, text)))
    assert len(out) == 200 and not valid(out) and est.counters.model_implausible == 200 - 59
    assert est.counters.model_non_finite == 0 and est.counters.invalid == 200
    assert said and said[0][0] == "model_implausible" and f"more than {IMPLAUSIBLE_ESTIMATE_FACTOR:g} times" in said[0][1]
    assert out[-1].values[FUSED][T.FUSED_FIELDS.index("fused_valid")] == 1.0  # the posterior: the measured force's
    assert_never_nan(out)
    # the model as shipped: every estimate of a full window valid, none refused
    est, out = run(model, in_order(episode, range(200)))
    assert est.counters.model_implausible == 0 and len(valid(out)) == 200 - 59


# ---------------------------------------------------------------------------------------- episodes

def test_no_window_spans_two_episodes_even_if_data_overtakes_episode_start(episode, model):
    """Episode k+1's stamps continue episode k's. Its first ticks may arrive before its
    episode_start; they must not extend episode k's window, and must not be lost either. While an
    ended episode's last ticks are still to come the estimator owes them (a node asked to stop
    then takes them first); not once they came, nor once the next episode started."""
    out = []
    est = OnlineEstimator(model, out.append)
    for t, m in in_order(episode, range(98)):
        est.add(t, m)
    assert not est.owes_ended_episode  # (mid-episode: a stop stops)
    est.end_episode(int(episode.stamps_ns[99]))  # the event overtakes the episode's last two ticks
    assert est.owes_ended_episode
    for t, m in in_order(episode, range(98, 99)):
        est.add(t, m)
    assert est.owes_ended_episode
    for t, m in in_order(episode, range(99, 100)):
        est.add(t, m)
    assert not est.owes_ended_episode
    assert [e.stamp_ns for e in valid(out)] == episode.stamps_ns[59:100].tolist()
    # "episode 2" = the same rows again, stamped right after episode 1
    base = int(episode.stamps_ns[99]) + int(episode.stamps_ns[1])
    stamps2 = [base + int(s) for s in episode.stamps_ns[:100]]
    for i in range(5):  # five ticks before its start event
        for t, m in tick_messages(episode, i, stamps2[i]):
            est.add(t, m)
    est.start_episode(stamps2[0])
    for i in range(5, 100):
        for t, m in tick_messages(episode, i, stamps2[i]):
            est.add(t, m)
    assert not est.owes_ended_episode
    est.end_episode(stamps2[99] + 5 * int(episode.stamps_ns[1]))  # an end whose ticks never come
    est.start_episode(stamps2[99] + 6 * int(episode.stamps_ns[1]))
    assert not est.owes_ended_episode  # (the next episode is under way)
    second = [e for e in valid(out) if e.stamp_ns >= stamps2[0]]
    assert [e.stamp_ns for e in second] == stamps2[59:], "window restarts at the episode's tick 0, keeping it"
    first = {e.stamp_ns - int(episode.stamps_ns[0]): e.values for e in valid(out) if e.stamp_ns < stamps2[0]}
    for e in second:  # same rows, same window -> the same estimate as in episode 1
        np.testing.assert_array_equal(e.values, first[e.stamp_ns - stamps2[0]])


def _two_episodes(est, episode, hole_ticks: int, *, stray_start: bool = False, overtaking: int = 0,
                  lost=(), last_a: int = 100):
    """Episode A (rows 0..last_a-1, its start and end announced), then episode B: the same 100 rows
    stamped ``hole_ticks`` after A's last tick, its start announced after ``overtaking`` of its
    ticks (a stray start far ahead before it, if asked); B's rows in ``lost`` never come. Returns
    B's stamps."""
    step = int(episode.stamps_ns[1])
    est.start_episode(int(episode.stamps_ns[0]))
    for t, m in in_order(episode, [i for i in range(last_a) if ("a", i) not in lost]):
        est.add(t, m)
    est.end_episode(int(episode.stamps_ns[last_a - 1]))
    base = int(episode.stamps_ns[last_a - 1]) + hole_ticks * step
    stamps = [base + int(episode.stamps_ns[i]) for i in range(100)]
    if stray_start:
        est.start_episode(stamps[0] + 100_000 * step)
    for i in range(100):
        if i == overtaking:
            est.start_episode(stamps[0])
        if i not in lost:
            for t, m in tick_messages(episode, i, stamps[i]):
                est.add(t, m)
    return stamps


@pytest.mark.parametrize(("hole_s", "overtaking"), [(2, 0), (2, 3), (12, 0)])
def test_the_stamps_between_an_ended_episode_and_the_next_are_no_gap(episode, model, hole_s, overtaking):
    """A replay of episodes 0 and 2 of a recording: the stamps of episode 1 between them were said
    to be "240 tick(s) missing" and counted as a gap (an outside tester's), also when the next
    episode's first ticks overtook its start (a reviewer's); 12 s apart, beyond the stream's
    ``MAX_AHEAD_TICKS``, its ticks were refused as far ahead, the stream restarted and its first
    ticks were lost (a reviewer's). Between an announced end and the next start nothing is due:
    the second episode is estimated as the first was. (Ticks that overtake a start more than
    ``MAX_AHEAD_TICKS`` after the end are refused as far ahead until it comes, and said as the
    episode's first ticks missing.)"""
    said = []
    est, out = run(model, [], warn=lambda key, text: said.append(key))
    stamps = _two_episodes(est, episode, hole_s * 60, overtaking=overtaking)
    c = est.counters
    assert (c.gaps, c.restarts, c.out_of_order, c.off_rate) == (0, 0, 0, 0) and not said, (c, said)
    second = [e for e in valid(out) if e.stamp_ns >= stamps[0]]
    assert [e.stamp_ns for e in second] == stamps[59:]
    first = {e.stamp_ns - int(episode.stamps_ns[0]): e.values for e in valid(out) if e.stamp_ns < stamps[0]}
    for e in second:  # a fresh episode: the same rows give the same estimates
        np.testing.assert_array_equal(e.values, first[e.stamp_ns - stamps[0]])
    said = []
    est, out = run(model, [], warn=lambda key, text: said.append(text))
    stamps = _two_episodes(est, episode, 12 * 60, overtaking=1)  # (refused until its start comes)
    c = est.counters
    assert (c.gaps, c.restarts, c.out_of_order) == (1, 0, len(INPUT_TOPICS))
    assert f"1 tick(s) missing before stamp {stamps[1]} ns (at an episode boundary)" in said[-1]
    assert [e.stamp_ns for e in valid(out) if e.stamp_ns >= stamps[0]] == stamps[60:]


def test_ticks_missing_at_an_episode_boundary_or_after_it_are_still_a_gap(episode, model):
    """What the boundary excuses is only the stamps between the ended episode and the next: its own
    lost ticks are counted as they are (one lost tick had been said as "240 tick(s) missing", a
    reviewer's), and a stray start far ahead between the end and the real start must not excuse
    ticks the next episode loses later (its window had spanned them, valid estimates across the
    hole; a reviewer's)."""
    for lost, said_count in (({("a", 99)}, 1), ({0}, 1), ({0, 1, 2}, 3)):
        said = []
        est, _ = run(model, [], warn=lambda key, text: said.append(text))
        _two_episodes(est, episode, 120, lost=lost)
        assert est.counters.gaps == 1 and said == [
            f"{said_count} tick(s) missing before stamp {said[0].split('stamp ')[1].split(' ns')[0]} ns (at an episode "
            "boundary); window reset"], said
    for stray in (False, True):
        said = []
        est, out = run(model, [], warn=lambda key, text: said.append(key))
        stamps = _two_episodes(est, episode, 120, stray_start=stray, lost=set(range(20, 30)))
        assert est.counters.gaps == 1 and said == ["gap"], (stray, said)
        after = {e.stamp_ns: e for e in out}
        assert not any(after[s].valid for s in stamps[30:30 + 59]), "no window spans the lost ticks"
        assert after[stamps[30 + 59]].valid


@pytest.mark.parametrize("overtaking", [1, 3])
def test_a_fresh_estimator_keeps_the_first_ticks_that_overtook_episode_start(episode, model, overtaking):
    """A replay into a fresh node: /sim/status and the data are separate topics, so the
    episode's first ticks may be released before its episode_start. They are the episode's
    (the stream began with them): every estimate, the fused soil and the path in soil equal
    those of the event coming first (a model with a distance term too)."""
    cfg = ModelConfig(**{**model.cfg.to_dict(), "extra_terms": [["compaction_hardening", 0.05]]})
    augmented = EstimatorNet(cfg, model.backbone.obs_mean, model.backbone.obs_std)
    augmented.load_state_dict(model.state_dict())
    augmented.eval()
    first = int(episode.stamps_ns[0])
    runs = {}
    for late in (False, True):
        out = []
        est = OnlineEstimator(augmented, out.append)
        for i in range(N_TICKS):
            if i == (overtaking if late else 0):
                est.start_episode(first)
            for t, m in tick_messages(episode, i):
                est.add(t, m)
        runs[late] = out
    assert len(valid(runs[True])) == N_TICKS - 59
    assert [e.stamp_ns for e in runs[True]] == [e.stamp_ns for e in runs[False]]
    np.testing.assert_array_equal(np.stack([e.values for e in runs[True]]), np.stack([e.values for e in runs[False]]))


def test_an_episode_start_after_an_older_episodes_ticks_still_restarts_a_fresh_stream(episode, model):
    """The other side of keeping overtaking ticks: a fresh node that first hears the tail of an
    earlier episode (stamps before the event's first) starts the window at the event."""
    out = []
    est = OnlineEstimator(model, out.append)
    for t, m in in_order(episode, range(70)):
        est.add(t, m)
    est.start_episode(int(episode.stamps_ns[50]))  # "time went back" to a start the stream passed
    assert est.buffer.count == 0
    assert len(valid(out)) == 70 - 59


@pytest.mark.parametrize("ended", [False, True])
def test_an_episode_started_again_at_the_same_stamps_is_estimated_as_by_a_fresh_node(episode, model, ended):
    """A simulator killed mid-episode (no episode_end) and started again: its new episode_start
    comes with stamps from 0 again. Every tick of the new episode is taken and estimated as a
    fresh node estimates it (live == replay): the first two had been refused as "far back"
    until they counted as a new stream (an outside tester's). With an episode_end between, the same."""
    first = int(episode.stamps_ns[0])
    est_out, fresh_out = [], []
    est = OnlineEstimator(model, est_out.append)
    est.start_episode(first)
    for t, m in in_order(episode, range(150)):
        est.add(t, m)
    if ended:
        est.end_episode(int(episode.stamps_ns[149]))
    del est_out[:]
    est.start_episode(first)
    fresh = OnlineEstimator(model, fresh_out.append)
    fresh.start_episode(first)
    for t, m in in_order(episode, range(N_TICKS)):
        est.add(t, m)
        fresh.add(t, m)
    assert est.counters.out_of_order == 0 and est.counters.restarts == 0
    assert [e.stamp_ns for e in est_out] == [e.stamp_ns for e in fresh_out] == episode.stamps_ns[:N_TICKS].tolist()
    np.testing.assert_array_equal(np.stack([e.values for e in est_out]), np.stack([e.values for e in fresh_out]))


def test_a_repeated_episode_start_changes_nothing_and_a_node_that_joined_midway_follows_a_restarted_source(
        episode, model):
    """The other side of the test above: the episode's start delivered again mid-episode is the same
    episode (restarting at once had emptied the window and the posterior: 91 of 141 valid estimates,
    a reviewer's), and a node that joined the episode midway (no start taken) and then hears a restarted
    simulator's start takes its ticks from 0 as a fresh node does (they had been refused as far back)."""
    first = int(episode.stamps_ns[0])
    fresh_out = []
    fresh = OnlineEstimator(model, fresh_out.append)
    fresh.start_episode(first)
    for t, m in in_order(episode, range(N_TICKS)):
        fresh.add(t, m)
    repeated_out = []
    est = OnlineEstimator(model, repeated_out.append)
    est.start_episode(first)
    for t, m in in_order(episode, range(150)):
        est.add(t, m)
    est.start_episode(first)
    for t, m in in_order(episode, range(150, N_TICKS)):
        est.add(t, m)
    midway_out = []
    joined = OnlineEstimator(model, midway_out.append)
    for t, m in in_order(episode, range(50, 150)):
        joined.add(t, m)
    del midway_out[:]
    joined.start_episode(first)
    for t, m in in_order(episode, range(N_TICKS)):
        joined.add(t, m)
    for out, node in ((repeated_out, est), (midway_out, joined)):
        assert node.counters.out_of_order == 0 and node.counters.restarts == 0
        assert [e.stamp_ns for e in out] == [e.stamp_ns for e in fresh_out]
        np.testing.assert_array_equal(np.stack([e.values for e in out]), np.stack([e.values for e in fresh_out]))


def test_a_late_copy_of_a_taken_tick_restarts_nothing_while_a_restart_is_in_question(episode, model):
    """A node that joined at tick 20 (a reorder horizon of 30 ticks) hears the episode's start at tick 40:
    whether its source started over is left to the ticks. A late copy of tick 25, one of its own stream's,
    is no new stream's first tick (it had restarted everything at the episode's start, a reviewer's)."""
    est = OnlineEstimator(model, lambda e: None, reorder_ticks=30)
    for t, m in in_order(episode, range(20, 40)):
        est.add(t, m)
    est.start_episode(int(episode.stamps_ns[0]))
    for t, m in in_order(episode, range(40, 100)):
        est.add(t, m)
    distance = est.distance_m
    for t, m in tick_messages(episode, 25):
        est.add(t, m)
    assert est.assembler.expected_restart_ns == int(episode.stamps_ns[0]) and not est._path_known
    assert est.distance_m == distance and est.buffer.count == 60


def test_time_going_far_back_starts_a_new_stream(episode, model):
    """A replay looped without /sim/status: stamps restart at 0; estimation restarts too, once two
    ticks' messages in a row have been stamped far back (the first two ticks of the replay)."""
    est, out = run(model, in_order(episode, range(100)) + in_order(episode, range(100)))
    assert est.counters.restarts == 1
    assert len(valid(out)) == 41 + (100 - 2 - 59)


def test_a_stray_message_far_back_or_ahead_keeps_the_soil_posterior(episode, model):
    """One message stamped 0, one tick stamped 2 s back, or one tick far in the future had restarted
    the stream: the soil posterior learnt along the path wiped mid-episode (an outside tester's). Each
    is refused and named, and the posterior and the estimates go on as without it."""
    clean_est, clean = run(model, in_order(episode, range(N_TICKS)))
    stamp = lambda i, offset: int(episode.stamps_ns[i]) + offset  # noqa: E731
    force = M.topic_rows(episode, T.BLADE_FORCE.name)[150]
    cases = {
        "one message stamped 0": [(T.BLADE_FORCE.name, M.build_message(M.TYPESTORE, T.BLADE_FORCE.name, 0, force))],
        "one tick 2 s back": [(t, M.build_message(M.TYPESTORE, t, stamp(150, -2 * M.NS_PER_S), M.topic_rows(episode, t)[150]))
                              for t in INPUT_TOPICS],
        "one tick 1e6 s ahead": [(t, M.build_message(M.TYPESTORE, t, stamp(150, 10**6 * M.NS_PER_S), M.topic_rows(episode, t)[150]))
                                 for t in INPUT_TOPICS],
    }
    for what, stray in cases.items():
        said = []
        est, out = run(model, in_order(episode, range(151)) + stray + in_order(episode, range(151, N_TICKS)),
                       warn=lambda kind, text: said.append(text))
        assert est.counters.restarts == 0 and est.counters.out_of_order == len(stray), what
        assert any("ignored (a new stream once 2 ticks of such stamps come in a row)" in s for s in said), (what, said)
        assert [e.stamp_ns for e in out] == [e.stamp_ns for e in clean], what
        assert np.array_equal(out[-1].values, clean[-1].values), what  # the posterior and the window as without it


def test_a_burst_of_copies_a_tick_back_resets_windows_but_never_the_soil_posterior(episode, model):
    """A second publisher's 40 copies of one Θ_k stamped a tick behind the newest: each out of order
    (its window reset), but 16 of them in a row had started a new stream, the soil posterior and map
    wiped mid-episode (an outside tester's); only stamps far back or ahead count towards one."""
    row = M.topic_rows(episode, T.KNOWN.name)[149]
    copies = [(T.KNOWN.name, M.build_message(M.TYPESTORE, T.KNOWN.name, int(episode.stamps_ns[149]), row))] * 40
    est, out = run(model, in_order(episode, range(151)) + copies + in_order(episode, range(151, N_TICKS)))
    assert est.counters.restarts == 0 and est.counters.out_of_order == 40
    assert [e for e in out if e.stamp_ns > episode.stamps_ns[150]], "estimates go on after the burst"


def test_ticks_arriving_twice_again_and_again_are_said_to_be_a_second_publisher(episode, model):
    """A controller left running from another launch answers every tick too: each copy spoils its
    tick (no window fills); after a few such ticks the warning says what it most likely is."""
    said = []
    est = OnlineEstimator(model, lambda e: None, warn=lambda kind, text: said.append(text))
    for i in range(6):
        messages = tick_messages(episode, i)
        copy = [m for m in messages if m[0] == T.BLADE_CMD.name][0]
        # both copies before the tick is complete (a duplicate), or one after it was released (stale)
        for topic, msg in ([copy] + [m for m in messages if m[0] != T.BLADE_CMD.name] + [copy]) if i % 2 else \
                ([copy, copy] + [m for m in messages if m[0] != T.BLADE_CMD.name]):
            est.add(topic, msg)
    repeats = [t for t in said if "two messages with stamp" in t or "(out of order)" in t]
    assert (est.counters.duplicates, est.counters.out_of_order, len(repeats)) == (3, 3, 6)
    assert all("second node publishing" not in t for t in repeats[:2])
    assert all("is a second node publishing this topic on this ROS_DOMAIN_ID" in t for t in repeats[2:]), repeats


@pytest.mark.parametrize("stride", [1, 3])
def test_a_dropped_tick_still_gets_an_invalid_estimate_so_a_lockstep_planner_is_not_left_waiting(episode, model, stride):
    """A duplicate /blade/force (a second writer's) spoils its tick, and a tick whose /blade/pose
    never comes is dropped: each still gets its estimate, invalid, in the stride's phase (a lockstep
    planner plans a tick once its estimate is in, and the controller waits for the plan: one
    duplicate cost the loop 2 s). The window refills after each, as before; stamps are said once."""
    clean_est, clean = run(model, in_order(episode, range(N_TICKS)), stride=stride)
    messages = []
    for i in range(N_TICKS):
        tick = tick_messages(episode, i)
        if i == 50:  # a second force first, then the tick's own
            tick = [m for m in tick if m[0] == T.BLADE_FORCE.name] + tick
        if i == 120:  # never gets its pose: overtaken by the ticks after it
            tick = [m for m in tick if m[0] != T.BLADE_POSE.name]
        messages += tick
    est, out = run(model, messages, stride=stride)
    assert est.counters.duplicates == 1 and est.counters.gaps >= 1
    assert [e.stamp_ns for e in out] == [e.stamp_ns for e in clean]  # every tick's estimate, in order, once
    got = {e.stamp_ns: e for e in out}
    for i in (50, 120):
        stamp = int(episode.stamps_ns[i])
        assert stamp in got or stride > 1  # (with a stride: if in its phase)
        if stamp in got:
            assert not got[stamp].valid and got[stamp].values[FILL] == 0
        # the window refills after each: invalid for the next 59 ticks, then valid as in the clean run
        refill = [e for e in out if stamp < e.stamp_ns < int(episode.stamps_ns[i + WINDOW_SAMPLES])]
        assert refill and not any(e.valid for e in refill)
    assert out[-1].valid and clean[-1].valid
    assert_never_nan(out)


def test_a_stray_stamped_off_the_streams_grid_is_refused_on_arrival_and_a_moved_phase_is_followed(episode, model):
    """One /blade/pose stamped 8 ms after a real tick (a stray writer's) was held as a tick of its
    own: the next real tick waited behind it for the reorder horizon, which in lockstep never
    comes (the planner loop stalled 2 s, an outside tester's). It is refused on arrival, named,
    and the estimates are the clean run's. A stream whose ticks all move to another phase (a bag
    replayed at another offset) is followed after two ticks' worth of refusals."""
    _, clean = run(model, in_order(episode, range(N_TICKS)))

    def stray(topic, i, offset_ns):
        return [(topic, M.build_message(M.TYPESTORE, topic, int(episode.stamps_ns[i]) + offset_ns,
                                        M.topic_rows(episode, topic)[i]))]

    # after tick 100: 8 ms on, 33 ns on, just short of tick 101's slot, two ticks on; 8 ms after tick 3;
    # then one between two ticks already taken (late: no window reset); and one stray sent 20 times
    cases = {"8 ms": (100, stray(T.BLADE_POSE.name, 100, 8_000_000), "8.0 ms off the stream's grid of ticks"),
             "33 ns": (100, stray(T.BLADE_FORCE.name, 101, 33), "33 ns off"),
             "0.67 ms short": (100, stray(T.BLADE_POSE.name, 100, 16_000_000), "0.7 ms off"),
             "2 ticks less 0.3 ms": (100, stray(T.KNOWN.name, 100, 33_033_333), "0.3 ms off"),
             "early": (3, stray(T.BLADE_POSE.name, 3, 8_000_000), "8.0 ms off"),
             "late": (100, stray(T.BLADE_POSE.name, 97, 5_000_000), "5.0 ms off"),
             "20 ticks ahead": (100, stray(T.BLADE_POSE.name, 120, 8_000_000), "8.0 ms off"),
             "20 copies": (100, stray(T.BLADE_POSE.name, 100, 8_000_000) * 20, "8.0 ms off")}
    for what, (after, messages, words) in cases.items():
        said = []
        est, out = run(model, in_order(episode, range(after + 1)) + messages + in_order(episode, range(after + 1, N_TICKS)),
                       warn=lambda kind, text: said.append(text))
        assert est.counters.out_of_order == len(messages) and est.counters.gaps == 0, what
        assert any(words in s for s in said), (what, said)
        assert [e.stamp_ns for e in out] == [e.stamp_ns for e in clean], what
        assert np.array_equal(np.stack([e.values for e in out]), np.stack([e.values for e in clean])), what
    # every tick from 120 on 5 ms later: two ticks refused, then the stream is followed at its new phase
    moved = in_order(episode, range(120)) + [m for i in range(120, N_TICKS) for m in
                                             tick_messages(episode, i, stamp=int(episode.stamps_ns[i]) + 5_000_000)]
    est, out = run(model, moved)
    taken = [e.stamp_ns for e in out if e.stamp_ns > int(episode.stamps_ns[119])]
    assert taken and taken[0] == int(episode.stamps_ns[122]) + 5_000_000 and len(taken) == N_TICKS - 122
    assert est.counters.restarts == 0


def test_a_second_stamp_one_ns_off_a_tick_is_a_stray_of_that_tick_not_a_tick_of_its_own(episode, model):
    """A writer stamping 1 ns off the grid (its stamps rounded, not floored: within the grid check's
    ±12 ns) sent a tick's force and Θ_k two ticks ahead: held as a tick of its own, it held the
    real tick back, reset the window and its invalid estimate went out 1 ns beside the real tick's,
    two estimates in one tick, which the recorder took for two writers and dropped 273 of 600 (an
    outside tester's). Now it is a stray of that tick: named, counted, and every estimate is the
    clean run's, whether the stray comes before its tick, amid it, or after it left. (A whole tick
    sent ahead under a near stamp is a tick like any other until its real one comes: no stamp tells.)"""
    _, clean = run(model, in_order(episode, range(N_TICKS)))

    def stray(i, offset_ns, topics=(T.BLADE_FORCE.name, T.KNOWN.name)):
        return [(t, M.build_message(M.TYPESTORE, t, int(episode.stamps_ns[i]) + offset_ns, M.topic_rows(episode, t)[i]))
                for t in topics]

    real = in_order(episode, range(N_TICKS))
    per_tick = len(INPUT_TOPICS)
    stray_words = "within a quarter tick of tick"
    cases = {"2 ticks ahead, 1 ns early": (101 * per_tick, stray(102, -1), 1, stray_words),
             "amid its tick, 1 ns late": (101 * per_tick + 1, stray(101, 1), 1, stray_words),
             "Θ_k alone 2 ns early": (101 * per_tick, stray(102, -2, (T.KNOWN.name,)), 1, stray_words),
             # (the tick it belongs to is the stream's last: the grid check refuses it on arrival)
             "after its tick left, 1 ns late": (102 * per_tick, stray(101, 1), 2, "1 ns off the stream's grid")}
    for what, (at, messages, refused, words) in cases.items():
        said = []
        est, out = run(model, real[:at] + messages + real[at:], warn=lambda kind, text: said.append(text))
        assert est.counters.gaps == 0 and est.counters.out_of_order == refused, (what, est.counters)
        assert any(words in s for s in said), (what, said)
        assert [e.stamp_ns for e in out] == [e.stamp_ns for e in clean], what
        assert np.array_equal(np.stack([e.values for e in out]), np.stack([e.values for e in clean])), what


def test_a_new_episode_a_few_ms_after_the_last_ones_end_loses_no_tick_to_the_stray_rule(episode, model):
    """A machine's or a bag's next episode may keep another phase: its first tick 5 ms after the last
    episode's last tick is a tick, not a stray of it (an outside reviewer's: it had been dropped,
    no estimate going out for it, which in lockstep leaves a planner waiting)."""
    said = []
    est = OnlineEstimator(model, (out := []).append, warn=lambda kind, text: said.append(kind))
    first = int(episode.stamps_ns[0])
    est.start_episode(first)
    for m in in_order(episode, range(150)):
        est.add(*m)
    last = int(episode.stamps_ns[149])
    est.end_episode(last)
    est.start_episode(last + 5_000_000)
    for i in range(150):
        for m in tick_messages(episode, i, stamp=last + 5_000_000 + int(episode.stamps_ns[i]) - first):
            est.add(*m)
    assert len(out) == 300 and "stray" not in said and est.counters.gaps == 0, (len(out), said, est.counters)


def test_legitimate_streams_keep_every_tick_under_the_grid_check(episode, model):
    """What the grid check must not refuse (a reviewer's cases): a new episode at another phase
    (a machine's, a bag's: its stamps 105 ms on), and a millisecond-rounded 61.8 Hz stream with
    gaps of 5 and 10 ticks. Every tick is taken: nothing is counted out of order or said off grid."""
    said = []
    est = OnlineEstimator(model, lambda e: None, warn=lambda kind, text: said.append(text))
    first = int(episode.stamps_ns[0])
    est.start_episode(first)
    for m in in_order(episode, range(100)):
        est.add(*m)
    est.end_episode(int(episode.stamps_ns[99]))
    shift = int(episode.stamps_ns[99]) + 105_000_000 - first  # (6.3 ticks on: within the checked reach)
    est.start_episode(first + shift)
    for i in range(100):
        for m in tick_messages(episode, i, stamp=int(episode.stamps_ns[i]) + shift):
            est.add(*m)
    assert est.counters.out_of_order == 0 and est.counters.samples == 200, said[:3]
    rounded = [round(k * 1e3 / 61.8) * 10**6 for k in range(150) if not (40 <= k < 45 or 90 <= k < 100)]
    est = OnlineEstimator(model, lambda e: None, warn=lambda kind, text: said.append(text))
    for k, stamp in enumerate(rounded):
        for m in tick_messages(episode, k, stamp=stamp):
            est.add(*m)
    assert est.counters.out_of_order == 0 and est.counters.samples == len(rounded), said[:3]
    # a machine's timer: 50 us of jitter, every 30th tick 1.5 ms late (a reviewer's: refused, every time)
    rng = np.random.default_rng(0)
    timed = [int(k * 1e9 / 60 + rng.normal(0, 50_000) + (1_500_000 if k % 30 == 29 else 0)) for k in range(150)]
    est = OnlineEstimator(model, lambda e: None, warn=lambda kind, text: said.append(text))
    for k, stamp in enumerate(timed):
        for m in tick_messages(episode, k, stamp=stamp):
            est.add(*m)
    assert est.counters.out_of_order == 0 and est.counters.samples == len(timed), said[-3:]
    assert not [s for s in said if "off the stream's grid" in s]


def test_incomplete_copies_seconds_back_that_restart_the_stream_are_not_estimated_a_second_time(episode, model):
    """A hostile node's copies of earlier ticks, stamped 2 s back and each missing a topic, restart
    the stream (two ticks of them in a row); dropped, each got an invalid estimate at a stamp the
    estimator had already published, with other values (the live hostile-node test caught it). No
    stamp is published twice, and the real ticks after them are estimated."""
    out = []
    est = OnlineEstimator(model, out.append)
    messages = in_order(episode, range(150))
    for j in range(30, 36):
        messages += [m for m in tick_messages(episode, j) if m[0] != T.BLADE_POSE.name]
    messages += in_order(episode, range(150, N_TICKS))
    for m in messages:
        est.add(*m)
    stamps = [e.stamp_ns for e in out]
    assert est.counters.restarts >= 1
    assert len(stamps) == len(set(stamps)), sorted(s for s in stamps if stamps.count(s) > 1)[:3]
    assert stamps[-1] == int(episode.stamps_ns[N_TICKS - 1])


def test_a_stray_before_an_ended_episodes_last_ticks_is_refused_and_a_dropped_first_tick_begins_the_next(
        episode, model):
    """The episode_end event overtakes the episode's last ticks: a stray 8 ms after tick 97 sent
    then was not checked (the next episode's grid was awaited) and held ticks 98 and 99 (a
    reviewer's). And a new episode whose first tick is dropped (a duplicate) gets its invalid
    estimate there, with the prior's fused fields, not the last episode's posterior."""
    out = []
    est = OnlineEstimator(model, out.append)
    first = int(episode.stamps_ns[0])
    est.start_episode(first)
    for m in in_order(episode, range(98)):
        est.add(*m)
    est.end_episode(int(episode.stamps_ns[99]))
    pose = M.topic_rows(episode, T.BLADE_POSE.name)[97]
    est.add(T.BLADE_POSE.name, M.build_message(M.TYPESTORE, T.BLADE_POSE.name, int(episode.stamps_ns[97]) + 8_000_000, pose))
    for m in in_order(episode, range(98, 100)):
        est.add(*m)
    assert est.counters.samples == 100 and est.counters.out_of_order == 1
    assert est.posterior.updates > 0 and out[-1].values[FUSED_VALID] == 1.0
    # the next episode, 1 s on; its first tick arrives with its force twice
    shift = int(episode.stamps_ns[99]) + 1_000_000_000 - first
    est.start_episode(first + shift)
    ticks = [tick_messages(episode, i, stamp=int(episode.stamps_ns[i]) + shift) for i in range(3)]
    ticks[0] = [m for m in ticks[0] if m[0] == T.BLADE_FORCE.name] + ticks[0]
    for tick in ticks:
        for m in tick:
            est.add(*m)
    assert est.counters.duplicates == 1
    new = [e for e in out if e.stamp_ns >= first + shift]
    assert [e.stamp_ns for e in new] == [int(episode.stamps_ns[i]) + shift for i in range(3)]
    assert not new[0].valid and new[0].values[FUSED_VALID] == 0.0  # the prior's, not the last episode's


@pytest.mark.parametrize("bad", [0, 121, 100000, True, 2.0])
def test_assembler_rejects_bad_reorder_horizon(bad):
    """(100000 was taken: no tick waits that long, one incomplete after 120 newer ones is dropped.)"""
    with pytest.raises(ValueError, match=rf"reorder_ticks={bad!r} must be an integer in \[1, 120\]"):
        SampleAssembler(print, reorder_ticks=bad)
    SampleAssembler(print, reorder_ticks=120)


# ---------------------------------------------------------------------------------------- checkpoints

class _Pickled:
    """A Python object in a checkpoint (torch.save pickles it)."""


def test_foreign_corrupt_and_physics_free_checkpoints_are_refused(tmp_path):
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(DEFAULT_CHECKPOINT.read_bytes()[:5000])
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    free = EstimatorNet(ModelConfig(kind="physics_free"), torch.zeros(9), torch.ones(9))
    baseline = save_checkpoint(tmp_path / "free.pt", free, train_config={}, dataset={}, split={}, metrics={}, history={})
    short_window = save_checkpoint(tmp_path / "w30.pt", EstimatorNet(ModelConfig(window=30), torch.zeros(9), torch.ones(9)),
                                   train_config={}, dataset={}, split={}, metrics={}, history={})
    pickled = tmp_path / "pickled.pt"  # an object torch would only load by unpickling it (running the file's code)
    torch.save({"model": _Pickled()}, pickled)
    for path, needle in ((corrupt, "not a readable torch checkpoint"), (foreign, "not an insitu-soil estimator"),
                         (pickled, "holds Python objects beyond tensors and plain containers, which are never unpickled"),
                         (baseline, "kind='physics_free'"), (short_window, "window=30 samples"), (tmp_path / "missing.pt", "does not exist")):
        with pytest.raises(ValueError, match=needle) as err:
            load_estimator_model(str(path))
        assert "checkpoint" in str(err.value)
    model, ckpt, resolved = load_estimator_model("")
    assert resolved == str(DEFAULT_CHECKPOINT) and model.cfg.kind == "pinn"


@pytest.mark.parametrize("term", [["compaction_hardening", 0.05], ["form:feex*tau", 0.3]])
def test_a_model_with_a_distance_term_gets_the_travel_since_the_episode_start(episode, model, term):
    """A PINN with compaction_hardening (a catalogue term on the travel) needs the blade's travel in soil since the
    episode began, one with a discovered form on time its time in soil: online each is summed
    tick by tick from episode_start and equals the offline pipeline's (the fused posterior's
    model has the term too); without an episode_start the node cannot know it and publishes invalid."""
    cfg = ModelConfig(**{**model.cfg.to_dict(), "extra_terms": [term]})
    augmented = EstimatorNet(cfg, model.backbone.obs_mean, model.backbone.obs_std)
    augmented.load_state_dict(model.state_dict())
    augmented.eval()
    offline = dict(zip(*episode_estimates(augmented, SAMPLE)))
    out = []
    est = OnlineEstimator(augmented, out.append)
    est.start_episode(int(episode.stamps_ns[0]))
    for t, m in in_order(episode, range(N_TICKS)):
        est.add(t, m)
    assert len(valid(out)) == N_TICKS - 59
    assert_matches_offline(valid(out), offline)
    plain = {e.stamp_ns: e.values for e in valid(run(model, in_order(episode, range(N_TICKS)))[1])}
    assert any(abs(e["f_x_hat"] - plain[e.stamp_ns][5]) > 10.0 for e in valid(out)), "the term adds force"
    _, blind = run(augmented, in_order(episode, range(N_TICKS)))
    assert blind and not valid(blind)


# ---------------------------------------------------------------------------------- fused soil

def test_the_fused_soil_rides_on_every_estimate_and_the_map_grows_along_the_path(episode, model, offline):
    maps = []
    est = OnlineEstimator(model, lambda e: None, publish_map=lambda stamp, rows: maps.append((stamp, rows)))
    out = []
    est.publish = out.append
    for topic, msg in in_order(episode, range(N_TICKS)):
        est.add(topic, msg)
    fused_valid = T.ESTIMATE_FIELDS.index("fused_valid")
    # nothing learnt before the first stretch, then every estimate (valid PINN window or not) carries it
    first = est.posterior.cfg.update_ticks
    assert all(e.values[fused_valid] == 0.0 for e in out[: first - 1])
    assert all(e.values[fused_valid] == 1.0 for e in out[first - 1 :])
    assert [e.values[STRETCHES] for e in out][-1] == len(maps) == est.posterior.updates
    # one map per stretch, stamped with the stretch's last sample; cells sorted by x, inside the path walked
    assert [s for s, _ in maps] == [int(episode.stamps_ns[k]) for k in range(first - 1, N_TICKS, first)]
    x = maps[-1][1][:, T.MAP_FIELDS.index("x")]
    assert np.all(np.diff(x) > 0) and x.min() >= episode.observations[0, 0] - 0.5
    assert np.isfinite(maps[-1][1]).all() and maps[-1][1].shape[1] == len(T.MAP_FIELDS)
    # and equals the offline track on the same episode
    assert_matches_offline(valid(out), offline)


def test_a_fused_posterior_no_soil_can_be_is_said_once_not_every_stretch(episode, model):
    """A strong gravel in the default world, cut live: its fused δ climbs to its highest value
    above φ (``SoilPosterior.not_a_soil``) and stays; the estimator says so once it has held for
    ``NOT_A_SOIL_STRETCHES`` stretches in a row, naming δ and φ, and publishes the fused soil all
    the same (its forces at other depths are what is calibrated). A catalogue soil's early
    posterior passes such corners for a few stretches: not said (the sample bag's loam)."""
    from pinn_estimator.fusion import NOT_A_SOIL_STRETCHES
    from soil_physics.soils import soil_from_dict
    from soil_sim_node.rollout import run_episodes
    from soil_sim_node.simulator import EpisodeSpec, SimConfig

    from .test_fusion import STRONG_GRAVEL

    (ep,) = run_episodes(SimConfig(world_mode="default"),
                         [EpisodeSpec(soil_from_dict(STRONG_GRAVEL), 50.0, 0.6, 0.12, seed=100, duration_s=8.0)])
    said, out = [], []
    est = OnlineEstimator(model, out.append, warn=lambda kind, text: said.append((kind, text)))
    for topic, msg in in_order(ep, range(len(ep.stamps_ns))):
        est.add(topic, msg)
    no_soil = [text for kind, text in said if kind == "not_a_soil"]
    assert len(no_soil) == 1 and "above phi" in no_soil[0] and "soil_discrepancy" in no_soil[0], said
    assert no_soil[0].endswith(f"(for {NOT_A_SOIL_STRETCHES} stretches in a row)") and est.posterior.updates > NOT_A_SOIL_STRETCHES
    assert out[-1].values[FUSED_VALID] == 1.0 and np.isfinite(out[-1].values).all()
    said.clear()
    loam = OnlineEstimator(model, lambda e: None, warn=lambda kind, text: said.append((kind, text)))
    for topic, msg in in_order(episode, range(len(episode.stamps_ns))):
        loam.add(topic, msg)
    assert loam.posterior.updates > NOT_A_SOIL_STRETCHES and not [t for k, t in said if k == "not_a_soil"], said


def test_a_dropped_tick_fuses_the_same_online_and_offline(episode, model):
    """A tick missing mid-cut: online the stretch in progress is dropped and no blade
    acceleration spans the gap; the offline track of the same rows with ``gap_before`` there
    (a repaired bag) learns the same, stretch for stretch."""
    keep = [i for i in range(N_TICKS) if i != 75]
    est, out = run(model, in_order(episode, keep))
    gap_before = np.array([i == 76 for i in keep])
    track = fused_track(est.posterior.cfg, episode.forces[keep], episode.known[keep],
                        distance_in_soil_of_known(episode.known[keep]), episode.observations[keep],
                        gap_before)
    online = np.stack([e.values[FUSED] for e in out])
    assert [e.stamp_ns for e in out] == [int(episode.stamps_ns[i]) for i in keep]
    np.testing.assert_allclose(online, track, rtol=1e-9, atol=1e-9)
    # the stretch 60..74 is dropped; the next ones count from the tick after the gap
    learnt_at = [keep[k] for k in range(1, len(out)) if out[k].values[STRETCHES] > out[k - 1].values[STRETCHES]]
    assert learnt_at == [29, 59, 105, 135, 165, 195]


def test_events_that_overtake_the_ticks_of_more_than_one_episode_still_start_each_window_and_posterior(
        episode, model):
    """A replay of bags in a row, faster than the node: episode A's end, B's start and end and C's
    start all come while A's ticks are still queued. Each episode's estimates are still those of
    its own rows alone, window and soil posterior (as a fresh node's); one pending boundary, the
    last event's, had let B's first ticks run on in A's window and posterior (an outside tester's:
    the first sand estimate still held the clay's cohesion). A late copy of B's start among them
    changes nothing."""
    n, period = 100, int(episode.stamps_ns[1])
    stamps = [[int(episode.stamps_ns[0]) + (k * n + i) * period for i in range(n)] for k in range(3)]
    out = []
    est = OnlineEstimator(model, out.append)
    est.start_episode(stamps[0][0])
    for k, ep_stamps in enumerate(stamps):
        for i, stamp in enumerate(ep_stamps):
            if (k, i) == (0, 40):
                est.end_episode(stamps[0][-1])
                est.start_episode(stamps[1][0])
                est.end_episode(stamps[1][-1])
                est.start_episode(stamps[1][0])  # a late copy of B's start (it drops no boundary)
                est.start_episode(stamps[2][0])
            for t, m in tick_messages(episode, i, stamp):
                est.add(t, m)
    by_stamp = {e.stamp_ns: e for e in out}
    assert len(by_stamp) == 3 * n
    for k in (1, 2):
        assert [by_stamp[s].values[FILL] for s in stamps[k][:3]] == [1.0, 2.0, 3.0]
        assert by_stamp[stamps[k][0]].values[STRETCHES] == 0.0
        for i in range(n):  # the same rows from the episode's start -> the same estimate as episode A's
            np.testing.assert_array_equal(by_stamp[stamps[k][i]].values, by_stamp[stamps[0][i]].values)


@pytest.mark.parametrize("stray", ["start", "end"])
def test_a_stray_event_far_ahead_leaves_no_boundary_that_resets_a_later_episode(episode, model, stray):
    """A stray episode_start mid-episode stamped a later episode's tick 50 (a node without a graph id
    takes any start), or a stray episode_end between episodes with such a last stamp: the real
    events after it, in stamp order, drop its boundary. Kept, it had cleared that later episode's
    window and soil posterior midway (a reviewer's)."""
    n, period = 100, int(episode.stamps_ns[1])
    stamps = [[int(episode.stamps_ns[0]) + (k * n + i) * period for i in range(n)] for k in range(3)]

    def run(with_stray):
        out = []
        est = OnlineEstimator(model, out.append)
        for k, ep_stamps in enumerate(stamps):
            est.start_episode(ep_stamps[0])
            for i, stamp in enumerate(ep_stamps):
                if with_stray and stray == "start" and (k, i) == (0, 40):
                    est.start_episode(stamps[2][50])
                for t, m in tick_messages(episode, i, stamp):
                    est.add(t, m)
            est.end_episode(ep_stamps[-1])
            if with_stray and stray == "end" and k == 0:
                est.end_episode(stamps[2][49])
        return {e.stamp_ns: e.values for e in out}

    clean, got = run(False), run(True)
    assert [got[s][FILL] for s in stamps[2][48:53]] == [49.0, 50.0, 51.0, 52.0, 53.0]
    for s in stamps[1] + stamps[2]:
        np.testing.assert_array_equal(got[s], clean[s])


def test_a_repeated_episode_end_after_the_next_episode_began_changes_nothing(episode, model):
    """An episode's end delivered again once the next episode's ticks have crossed its boundary (a
    late copy, or a node that hears /sim/status twice) is that boundary again, crossed already: it
    had been pending once more, and the next tick restarted the episode under way's stride phase,
    path and soil posterior midway (a reviewer's)."""
    n, period = 100, int(episode.stamps_ns[1])
    stamps = [[int(episode.stamps_ns[0]) + (k * n + i) * period for i in range(n)] for k in range(2)]

    def run(repeat):
        out = []
        est = OnlineEstimator(model, out.append, stride=3)
        for k, ep_stamps in enumerate(stamps):
            est.start_episode(ep_stamps[0])
            for i, stamp in enumerate(ep_stamps):
                if repeat and (k, i) == (1, 70):
                    est.end_episode(stamps[0][-1])
                for t, m in tick_messages(episode, i, stamp):
                    est.add(t, m)
            est.end_episode(ep_stamps[-1])
        return {e.stamp_ns: e.values for e in out}

    clean, got = run(False), run(True)
    assert got.keys() == clean.keys()  # (the stride phase kept)
    second = [s for s in stamps[1] if s in clean]
    assert clean[second[-1]][STRETCHES] > clean[second[len(second) // 2]][STRETCHES]
    for s in second:
        np.testing.assert_array_equal(got[s], clean[s])


@pytest.mark.parametrize("b_start_overtakes", [False, pytest.param(True, marks=pytest.mark.xfail(
    strict=True, reason="known gap: the second start, which the old stream is past as well, puts the restart in "
                        "question at its own stamp; the new stream is taken only once its ticks were refused as far "
                        "back (196 of 200 estimates, all different). Keeping the first question open across later "
                        "events, tried, let a stray copy of the first tick replay them (two reviewers'): left open"))])
def test_a_replay_started_over_whose_first_end_overtakes_its_ticks_is_estimated_as_by_a_fresh_node(
        episode, model, b_start_overtakes):
    """A replay started over while the node is midway through its second episode, the first
    episode's start and end overtaking that episode's ticks: the node estimates the replay as a
    fresh node does. The end is of the new stream, not a copy of the old one's (taken as a copy it
    had kept ticks of the new stream from restarting it: 100 of 200 estimates differed, a
    reviewer's). With the second start overtaking them too: a known gap (the mark)."""
    n, period = 100, int(episode.stamps_ns[1])
    a = [int(episode.stamps_ns[0]) + i * period for i in range(n)]
    b = [a[-1] + (i + 1) * period for i in range(n)]

    def feed(est, ep_stamps, count=n):
        for i, stamp in enumerate(ep_stamps[:count]):
            for t, m in tick_messages(episode, i, stamp):
                est.add(t, m)

    def replay(est):
        est.start_episode(a[0])
        est.end_episode(a[-1])
        if b_start_overtakes:
            est.start_episode(b[0])
        feed(est, a)
        if not b_start_overtakes:
            est.start_episode(b[0])
        feed(est, b)
        est.end_episode(b[-1])

    fresh_out = []
    replay(OnlineEstimator(model, fresh_out.append))
    out = []
    est = OnlineEstimator(model, out.append)
    est.start_episode(a[0])
    feed(est, a)
    est.end_episode(a[-1])
    est.start_episode(b[0])
    feed(est, b, 50)
    del out[:]
    replay(est)
    assert [e.stamp_ns for e in out] == [e.stamp_ns for e in fresh_out] == a + b
    np.testing.assert_array_equal(np.stack([e.values for e in out]), np.stack([e.values for e in fresh_out]))


@pytest.mark.parametrize("stray", ["message", "tick"])
def test_a_stray_copy_of_the_first_tick_after_a_repeated_start_and_the_episodes_end_restarts_nothing(episode, model, stray):
    """A late copy of the episode's start, then its end and the next start: the end closes the
    restart in question. A stray copy of the first tick (one message, or a whole tick) in the next
    episode then restarts nothing (with the question kept open across later events, tried, it
    replayed the end and start, resetting the next episode's window and posterior midway, and
    with a whole tick a stamp was estimated twice: a reviewer's)."""
    n, period = 200, int(episode.stamps_ns[1])
    a = [int(episode.stamps_ns[0]) + i * period for i in range(n)]
    b = [a[-1] + (i + 1) * period for i in range(n)]

    def feed(est, stamps, rows):
        for stamp, i in zip(stamps, rows):
            for t, m in tick_messages(episode, i, stamp):
                est.add(t, m)

    def run(perturbed):
        out = []
        est = OnlineEstimator(model, out.append)
        est.start_episode(a[0])
        feed(est, a[:150], range(150))
        if perturbed:
            est.start_episode(a[0])
        feed(est, a[150:], range(150, n))
        est.end_episode(a[-1])
        est.start_episode(b[0])
        feed(est, b[:100], range(100))
        if perturbed:
            for t, m in tick_messages(episode, 0, a[0])[: 1 if stray == "message" else None]:
                est.add(t, m)
        feed(est, b[100:], range(100, n))
        return est, out

    (_, clean), (est, got) = run(False), run(True)
    assert est.counters.restarts == 0 and est.assembler.expected_restart_ns is None
    assert [e.stamp_ns for e in got] == [e.stamp_ns for e in clean]
    np.testing.assert_array_equal(np.stack([e.values for e in got]), np.stack([e.values for e in clean]))


def test_a_source_started_over_after_a_repeated_start_and_later_events_is_estimated_as_by_a_fresh_node(episode, model):
    """A late copy of the episode's start, its end and the next start, then the source starts over
    at the first stamp with a longer episode: the new stream is estimated as by a fresh node, none
    of the old stream's events in it (with the question kept open across later events, tried, the
    old end was taken again and reset the new episode's window and posterior midway: 100
    estimates different from a fresh node's, a reviewer's)."""
    n, period = 200, int(episode.stamps_ns[1])
    a = [int(episode.stamps_ns[0]) + i * period for i in range(n)]
    b = [a[-1] + (i + 1) * period for i in range(n)]
    c = [a[0] + i * period for i in range(300)]

    def feed(est, stamps, first_row=0):
        for i, stamp in enumerate(stamps, first_row):
            for t, m in tick_messages(episode, i, stamp):
                est.add(t, m)

    fresh_out = []
    fresh = OnlineEstimator(model, fresh_out.append)
    fresh.start_episode(c[0])
    feed(fresh, c)
    out = []
    est = OnlineEstimator(model, out.append)
    est.start_episode(a[0])
    feed(est, a[:150])
    est.start_episode(a[0])
    feed(est, a[150:], 150)
    est.end_episode(a[-1])
    est.start_episode(b[0])
    feed(est, b[:50])
    del out[:]
    est.start_episode(c[0])
    feed(est, c)
    assert [e.stamp_ns for e in out] == [e.stamp_ns for e in fresh_out]
    np.testing.assert_array_equal(np.stack([e.values for e in out]), np.stack([e.values for e in fresh_out]))


def test_a_new_episode_restarts_the_soil_posterior(episode, model):
    est, out = run(model, in_order(episode, range(120)))
    assert est.posterior.updates == 4
    start = int(episode.stamps_ns[-1]) + 10**9
    est.start_episode(start)
    assert est.posterior.updates == 4  # until the new episode's first sample comes
    for topic, msg in tick_messages(episode, 0, stamp=start):
        est.add(topic, msg)
    assert est.posterior.updates == 0 and not est.soil_map.cells
    assert est._fused[T.FUSED_FIELDS.index("fused_valid")] == 0.0


def test_a_model_with_other_physics_restarts_the_posterior_and_the_same_keeps_it(episode, model):
    est, _ = run(model, in_order(episode, range(120)))
    est.set_model(model)
    assert est.posterior.updates == 4
    other = EstimatorNet(ModelConfig(extra_terms=(("soil_inertia", 4.0),)), torch.zeros(9), torch.ones(9))
    est.set_model(other)
    shipped = load_calibrated(DEFAULT_WORLD).terms  # the terms the calibrated config adds itself
    assert est.posterior.updates == 0 and est.posterior.cfg.terms == (("soil_inertia", 4.0), *shipped)
    est.set_model(model)  # back: the new model's terms do not stay behind
    assert est.posterior.cfg.terms == shipped


# ------------------------------------------------------------------------- a machine's streams
def test_a_stream_at_another_rate_gives_no_estimate_and_says_its_rate(model, episode):
    """A 50 Hz machine's ticks (stamps 20 ms apart) were estimated on as 60 Hz, windows of 1.2 s
    (an outside tester's); a 60 Hz stream with millisecond stamps is still taken."""
    warned = []
    est, out = run(model, [m for i in range(N_TICKS) for m in tick_messages(episode, i, stamp=i * 20_000_000)],
                   warn=lambda kind, text: warned.append((kind, text)))
    assert not valid(out) and est.counters.off_rate > 0
    # nor a soil learnt from its first ticks, before the rate was judged (the planner plans from fused_valid):
    # forgotten once judged, the one stretch of them said at most on the tick before
    assert est.posterior.updates == 0 and sum(e.values[FUSED_VALID] for e in out) <= 1, est.posterior.updates
    assert any(kind == "rate" and "every 20 ms (50 Hz)" in text for kind, text in warned), warned[:3]
    # 120 Hz: every other tick is no stray of the one before (half a tick apart), and the rate is said
    warned.clear()
    est, out = run(model, [m for i in range(N_TICKS) for m in tick_messages(episode, i, stamp=i * 1_000_000_000 // 120)],
                   warn=lambda kind, text: warned.append((kind, text)))
    assert not valid(out) and est.counters.off_rate > 0 and not any(kind == "stray" for kind, _ in warned)
    assert any(kind == "rate" and "(120 Hz)" in text for kind, text in warned), warned[:3]
    _, out = run(model, [m for i in range(N_TICKS) for m in tick_messages(episode, i, stamp=round(i * 1e3 / 60) * 10**6)])
    assert len(valid(out)) == N_TICKS - WINDOW_SAMPLES + 1


def test_a_force_of_the_other_sign_is_said_and_the_right_one_is_not(model, episode):
    flipped = Episode(meta=episode.meta, stamps_ns=episode.stamps_ns, observations=episode.observations,
                      forces=-episode.forces, extras=episode.extras, known=episode.known, truth=episode.truth)
    for ep, said in ((episode, False), (flipped, True)):
        warned = []
        run(model, in_order(ep, range(N_TICKS)), warn=lambda kind, text: warned.append(kind))
        assert ("force_sign" in warned) is said
