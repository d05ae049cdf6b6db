"""The online sample assembler and stamps nobody can mean: refused as malformed with a warning,
never an exception (log formatting included), and the following real ticks are still used."""
from __future__ import annotations

import numpy as np
import pytest

from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import TICK_PERIOD_NS
from pinn_estimator.online import INPUT_TOPICS, RESTART_AFTER_REFUSED, ROUTES, SampleAssembler


def _tick(stamp: int) -> list[tuple[str, object]]:
    return [(t, M.build_message(M.TYPESTORE, t, stamp, [0.1] * len(ROUTES[t]))) for t in INPUT_TOPICS]


def _stamp(k: int) -> int:
    return int(k * TICK_PERIOD_NS)


class Collect:
    def __init__(self):
        self.samples, self.warnings = [], []

    def on_sample(self, stamp, sample):
        self.samples.append((stamp, sample is not None))

    def warn(self, kind, text):
        self.warnings.append((kind, text))


@pytest.mark.parametrize("sec", (1e308, -1e308, 2.0**63, -(2.0**63)))
def test_a_labelled_stamp_beyond_the_graphs_range_is_malformed_not_a_crash(sec):
    got = Collect()
    asm = SampleAssembler(got.on_sample, warn=got.warn)
    for k in range(5):
        for topic, msg in _tick(_stamp(k)):
            asm.add(topic, msg)
    bogus = M.build_message(M.TYPESTORE, T.KNOWN.name, 0, [0.1] * len(ROUTES[T.KNOWN.name]))
    bogus.data[0] = sec
    asm.add(T.KNOWN.name, bogus)
    assert asm.counters.malformed == 1 and asm.counters.restarts == 0
    assert any("stamp_sec" in text for _, text in got.warnings)
    for k in range(5, 10):
        for topic, msg in _tick(_stamp(k)):
            asm.add(topic, msg)
    released = [s for s, ok in got.samples if ok]
    assert released[-5:] == [_stamp(k) for k in range(5, 10)]  # the ticks after the bogus message are samples


def test_a_whole_tick_stamped_far_in_the_future_does_not_break_the_restart_warning():
    """All inputs of one tick stamped at the graph's last second, then real ticks again: the first
    real tick is refused as far back, the second with it a new stream (time went back), each
    reported in a log line that must format."""
    got = Collect()
    asm = SampleAssembler(got.on_sample, warn=got.warn)
    far = M.MAX_STAMP_NS
    for topic, msg in _tick(far):
        asm.add(topic, msg)
    for k in (1, 2):
        for topic, msg in _tick(_stamp(k)):
            asm.add(topic, msg)
    assert asm.counters.restarts == 1
    assert any(kind == "restart" for kind, _ in got.warnings)
    assert any(kind.endswith(":far") and "s before the last sample" in text for kind, text in got.warnings)


def test_the_restart_warning_formats_any_integer_distance():
    got = Collect()
    asm = SampleAssembler(got.on_sample, warn=got.warn)
    values = np.full(len(ROUTES[T.KNOWN.name]), 0.1)
    asm.reset(10**400)  # stamps the assembler was handed directly, beyond any float
    for _ in range(RESTART_AFTER_REFUSED):  # refused as far back, then (with these) a new stream
        asm.add_values(T.KNOWN.name, 0, values)
    (text,) = [text for kind, text in got.warnings if kind == "restart"]
    assert "s before the last sample" in text
    # (nothing had left since the reset: refused before the stamp the stream is expected from)
    assert any(f"s before the stream's expected start {10**400} ns" in text
               for kind, text in got.warnings if kind.endswith(":far"))


def test_a_stamp_far_ahead_of_a_stream_with_no_tick_yet_names_its_expected_start_not_minus_one():
    """A fresh stream expected from stamp 0 refused a tick 15.75 s ahead "after the last sample -1
    ns" (an outside tester's): it names the start it is expected from; after a tick, that tick."""
    got = Collect()
    asm = SampleAssembler(got.on_sample, warn=got.warn)
    asm.reset(0)
    for topic, msg in _tick(_stamp(945)):  # 15.75 s
        asm.add(topic, msg)
    far = [text for kind, text in got.warnings if kind.endswith(":far")]
    assert far and "s after the stream's expected start 0 ns" in far[0] and "-1 ns" not in far[0]
    got.warnings.clear()
    for k in (0, 1):
        for topic, msg in _tick(_stamp(k)):
            asm.add(topic, msg)
    for topic, msg in _tick(_stamp(2000)):
        asm.add(topic, msg)
    far = [text for kind, text in got.warnings if kind.endswith(":far")]
    assert far and f"s after the last sample {_stamp(1)} ns" in far[0]


def test_topics_stamped_each_by_its_own_sensor_are_said_to_be_so():
    """A machine whose topics carry their sensors' own stamps (2 ms apart) gave 5640 lines of 'never got'
    naming topics that did come (an outside tester's): now the line says they come, stamped otherwise."""
    got = Collect()
    asm = SampleAssembler(got.on_sample, warn=got.warn)
    rng = np.random.default_rng(0)
    for k in range(1, 200):
        for topic in INPUT_TOPICS:
            stamp = _stamp(k) + int(rng.integers(-2_000_000, 2_000_000))
            asm.add(topic, M.build_message(M.TYPESTORE, topic, stamp, [0.1] * len(ROUTES[topic])))
    evicted = [text for kind, text in got.warnings if kind == "evicted"]
    assert evicted and "stamped otherwise: every topic of a tick must carry the tick's stamp" in evicted[0]
    assert not any(ok for _, ok in got.samples)
