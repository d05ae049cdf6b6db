"""Writers told apart by publication sequence continuity (no ROS)."""
from __future__ import annotations

from soil_msgs_py.writer_identity import (
    SEQUENCE_MASK, SUCCESSOR_MIN_MESSAGES, WriterTracks, leading_chain, succession, successor_min_messages, tick_index,
    tick_number,
)


def test_tick_index_is_the_grid_and_tick_number_counts_across_episodes():
    assert [tick_index(10**9 * k // 60 + 5, 5) for k in range(4)] == [0, 1, 2, 3]
    assert tick_index(5 + 10**9 // 120, 5) is None and tick_index(4, 5) is None
    last = 239 * 10**9 // 60
    assert tick_number(last) == 239 and tick_number(last + 16_666_667) == 240


def test_every_tick_writer_leads_and_a_sporadic_intruder_has_its_own_writer():
    w = WriterTracks()
    ids = [w.observe(1 + k, k) for k in range(10)]
    assert len(set(ids)) == 1
    hostile = [w.observe(500 + j, 3 * j) for j in range(3)]  # its own counter, every third tick
    assert len(set(hostile)) == 1 and hostile[0] != ids[0]
    assert w.leader() == ids[0] and w.leads(ids[0]) and not w.leads(hostile[0])


def test_a_skipped_tick_continues_the_writer_and_a_repeat_does_not():
    w = WriterTracks()
    a = w.observe(7, 0)
    assert w.observe(8, 2) == a  # tick 1 skipped: the counter still continues
    assert w.observe(9, 2) != a  # a second message for one tick is not the same writer's
    assert w.observe(9, 3) == a


def test_unknown_sequences_are_not_judged_and_ties_have_no_leader():
    w = WriterTracks()
    assert w.observe(None, 0) is None and w.observe(0, 1) is None and w.leads(None)
    assert w.leader() is None
    w.observe(1, 0)
    w.observe(50, 0)
    assert w.leader() is None


def test_a_tie_on_ticks_goes_to_the_writer_heard_first():
    w = WriterTracks()
    first = w.observe(100, 0)
    newcomer = w.observe(1, 1)  # its own counter, one tick like the first writer
    assert newcomer != first and w.leads(first) and not w.leads(newcomer)
    w.observe(2, 2)  # the newcomer's second tick: now it is ahead
    assert w.leads(newcomer) and not w.leads(first)


def test_sequence_numbers_wrap_like_mcaps_uint32():
    w = WriterTracks()
    a = w.observe(SEQUENCE_MASK, 0)
    assert w.observe(SEQUENCE_MASK + 1, 1) == a  # 2^32: stored as 0 in MCAP


def test_a_silent_writer_is_forgotten_so_a_restarted_one_is_followed():
    w = WriterTracks(forget_after_ticks=5)
    old = [w.observe(100 + k, k) for k in range(20)][0]
    new = w.observe(1, 30)
    assert new != old and w.leads(new)


def test_the_whole_recording_keeps_the_writer_whose_claim_an_intruder_filled_in_a_gap():
    """Writer: ticks 0..9 with sequence 1..9, tick 4 skipped. An intruder claims tick 4 with
    sequence 5 (what the writer sends next, at tick 5). Chains: the writer's 9 messages, or the
    intruder's message in place of the writer's tick 5: equally long, so the weights decide."""
    ticks = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    seqs = [1, 2, 3, 4, 5, 5, 6, 7, 8, 9]  # index 4 is the intruder's
    writer = {0, 1, 2, 3, 5, 6, 7, 8, 9}
    assert leading_chain(ticks, seqs, [1 if i == 4 else 2 for i in range(10)]) == writer
    # Arrival order alone would take the intruder for the writer and the writer's tick 5 for a stranger.
    w = WriterTracks()
    ids = [w.observe(s, k) for k, s in zip(ticks, seqs)]
    assert ids[4] == ids[0] and ids[5] != ids[0]


def test_a_chain_rises_by_at_most_the_ticks_between_and_ties_have_no_leader():
    assert leading_chain([0, 1, 2, 3], [1, 2, 9, 10]) is None  # two chains of two: a tie
    assert leading_chain([0, 1, 2, 3, 4], [1, 2, 9, 10, 3]) == {0, 1, 4}  # tick 2, 3 skipped
    assert leading_chain([0, 0, 1, 1], [1, 1, 2, 2]) is None  # two writers meeting every tick
    assert leading_chain([], []) is None


def test_a_restarted_writer_is_led_by_its_longer_stretch_and_the_counter_may_wrap():
    ticks = list(range(12))
    assert leading_chain(ticks, [100, 101, 102, 103, 1, 2, 3, 4, 5, 6, 7, 8]) == set(range(4, 12))
    top = SEQUENCE_MASK - 2
    wrapped = [(top + k) & SEQUENCE_MASK for k in range(6)]  # ..., 2^32 - 1, 0, 1, 2
    assert leading_chain(list(range(6)), wrapped) == set(range(6))


def test_succession_keeps_a_restarted_writer_and_its_predecessor_but_no_interleaved_intruder():
    """Writer A: ticks 0..39, sequence 1..40; silent 60 ticks (beyond the silence limit 5);
    writer B (restarted, a new counter): ticks 100..199, sequence 1..100, whose numbers from 41
    on continue A's counter. An intruder (sequence 500..) claims ticks 150 and 160 among B's."""
    ticks = list(range(40)) + list(range(100, 200)) + [150, 160]
    seqs = list(range(1, 41)) + list(range(1, 101)) + [500, 501]
    a, b = set(range(40)), set(range(40, 140))
    lead = leading_chain(ticks, seqs)
    assert lead == a | set(range(80, 140))  # A with B's tail (60): B's first 40 ("head") are off it
    # cut at the silence, B's tail is the longest stretch; before it A and B's head tie (40 each),
    # one after the other: both kept, and so the whole of B with its tail
    assert succession(ticks, seqs, lead, max_silence_ticks=5) == a | b
    assert succession(ticks, seqs, b, max_silence_ticks=5) == a | b  # led by B: A before it
    # only eligible messages are taken beside the chain given; with no silence beyond the limit the
    # restarted counter inside the chain's gap (numbers below A's last) still cuts it
    assert succession(ticks, seqs, b, [i not in a for i in range(len(ticks))], max_silence_ticks=5) == b
    assert succession(ticks, seqs, lead, max_silence_ticks=200) == a | b
    assert succession(ticks, seqs, set()) == set()


def test_a_restarted_writer_of_a_sparse_topic_is_its_predecessors_successor():
    """The estimator's map, one message every 30 ticks (2 Hz): killed after 21 maps, restarted with a
    new counter 4 s later, 26 maps (13 s). Half a second of a 2 Hz topic's messages is not 30 of them:
    both writers are kept (the restarted one's had been refused, an outside tester's); a stray
    writer's one map in the silence between them is not."""
    a_ticks, b_ticks = [30 * k for k in range(21)], [840 + 30 * k for k in range(26)]
    ticks, seqs = a_ticks + [720] + b_ticks, list(range(1, 22)) + [900] + list(range(1, 27))
    a, b = set(range(21)), set(range(22, 48))
    assert successor_min_messages(a_ticks) == 2 and successor_min_messages(range(100)) == SUCCESSOR_MIN_MESSAGES == 30
    for lead in (a, b, leading_chain(ticks, seqs)):
        assert succession(ticks, seqs, lead) == a | b
    # two maps of a second writer (a fresh counter) between two of the writer's, 30 ticks apart: an
    # intruder's, not a successor (two messages are enough only where the writer is not publishing)
    ticks, seqs = a_ticks + [305, 310], list(range(1, 22)) + [1, 2]
    assert succession(ticks, seqs, leading_chain(ticks, seqs)) == a


def test_succession_takes_no_stray_writer_beside_the_leader():
    """A few plausible messages of an intruder's own counter in a silence of the writer (fewer than
    a restarted node would send) stay out."""
    ticks = list(range(40)) + [60, 61, 62] + list(range(100, 140))
    seqs = list(range(1, 41)) + [700, 701, 702] + list(range(41, 81))  # the writer, silent 60 ticks, goes on
    writer = set(range(40)) | set(range(43, 83))
    assert leading_chain(ticks, seqs) == writer
    assert succession(ticks, seqs, writer, max_silence_ticks=5) == writer  # its two stretches; not the stray three


def test_succession_cuts_a_chain_where_a_restarted_counter_runs_inside_its_gap():
    """A sent 40 messages and was restarted at once (20 ticks later): no silence beyond the limit
    between A and the new counter's tail, but the new counter's first numbers lie inside that gap,
    below A's last: a restart. Both writers are kept whole."""
    ticks = list(range(40)) + list(range(60, 160))
    seqs = list(range(1, 41)) + list(range(1, 101))
    lead = leading_chain(ticks, seqs)
    assert lead == set(range(40)) | set(range(80, 140))
    assert succession(ticks, seqs, lead) == set(range(140))
    # the same numbers from a writer not eligible (an intruder's garbage) cut nothing
    assert succession(ticks, seqs, lead, [i < 40 or i >= 80 for i in range(140)]) == lead


def test_a_second_publisher_in_the_ticks_a_writer_skips_does_not_cut_it_up():
    """A writer that skips every 10th tick, and a second publisher (its own counter, lower numbers)
    whose messages land in those skipped ticks: a few messages behind the writer's number in each
    gap are no restarted counter, so the writer is kept whole and the second publisher's refused."""
    writer = [k for k in range(300) if k % 10 != 5]
    ticks = writer + [k for k in range(300) if k % 10 == 5]
    seqs = list(range(1000, 1000 + len(writer))) + list(range(1, 31))
    lead = leading_chain(ticks, seqs)
    assert lead == set(range(len(writer)))
    assert succession(ticks, seqs, lead) == lead
