"""The command gate follows the controller's writer: a spoofed command for the tick being
answered that arrives first, from another writer, neither steers the simulator nor pushes
out the controller's command (no ROS: sequence numbers given as DDS's message info does)."""
from __future__ import annotations

import math

from soil_msgs_py.graph import COMMAND_TOPICS
from soil_sim_node.live import CommandGate

TICK_NS = 10**9 // 60
BLADE, CHASSIS = "/blade/cmd", "/chassis/cmd_vel"
assert set(COMMAND_TOPICS) == {BLADE, CHASSIS}


def stamp(k: int) -> int:
    return k * 10**9 // 60


def answer(gate: CommandGate, k: int, seq: int, u_zr: float = 0.05, u_x: float = 0.5):
    return (gate.offer(BLADE, stamp(k), (u_zr, 0.0), seq) + gate.offer(CHASSIS, stamp(k), (u_x,), seq))


def run_controller(gate: CommandGate, ticks: int, seq0: int = 1) -> int:
    """The controller answers ``ticks`` ticks; returns its next sequence number."""
    for k in range(ticks):
        gate.expect(stamp(k))
        assert answer(gate, k, seq0 + k) == []
        gate.take()
    return seq0 + ticks


def test_a_spoofed_command_arriving_first_does_not_steer_and_the_controllers_is_applied():
    gate = CommandGate()
    seq = run_controller(gate, 10)
    gate.expect(stamp(10))
    warnings = gate.offer(BLADE, stamp(10), (1e308, 0.0), 500)  # another writer's counter, first
    assert any("/blade/cmd" in text and str(stamp(10)) in text for _, text in warnings), warnings
    assert not gate.complete
    assert answer(gate, 10, seq, u_zr=0.07, u_x=0.4) == []  # the controller's, second
    assert gate.complete
    assert gate.take() == (0.07, 0.0, 0.4)


def test_an_intruder_taken_on_the_very_first_tick_is_not_followed_afterwards():
    gate = CommandGate()
    gate.expect(stamp(0))
    gate.offer(BLADE, stamp(0), (0.3, 0.0), 900)  # tick 0: nobody is known yet; taken
    answer(gate, 0, 1, u_zr=0.05)
    assert gate.take()[0] == 0.3  # nothing tells the writers apart on the very first tick
    for k in range(1, 4):
        gate.expect(stamp(k))
        assert answer(gate, k, 1 + k, u_zr=0.05) == []
        gate.take()
    gate.expect(stamp(4))
    assert gate.offer(BLADE, stamp(4), (0.3, 0.0), 901) != []
    assert answer(gate, 4, 5, u_zr=0.06) == []
    assert gate.take() == (0.06, 0.0, 0.5)


def test_an_intruder_that_ties_the_controller_early_does_not_steer():
    """Tick 1: the controller has answered one tick; an intruder's first copy of tick 1 (its own
    fresh counter: one tick, a tie) arrives before the controller's. A tie goes to the writer
    heard first, so the copy is refused and the controller's command is applied."""
    gate = CommandGate()
    seq = run_controller(gate, 1)
    gate.expect(stamp(1))
    assert gate.offer(BLADE, stamp(1), (0.3, 0.0), 1) != []  # the intruder's counter starts at 1
    assert answer(gate, 1, seq, u_zr=0.06) == []
    assert gate.take()[0] == 0.06


def test_a_controller_that_skipped_a_tick_is_still_followed():
    gate = CommandGate()
    seq = run_controller(gate, 5)
    gate.expect(stamp(5))
    gate.take()  # the controller never answered tick 5 (real time: held)
    gate.expect(stamp(6))
    assert gate.offer(BLADE, stamp(6), (1e308, 0.0), 77) != []  # an intruder first
    assert answer(gate, 6, seq, u_zr=0.08) == []
    assert gate.take()[0] == 0.08


def test_a_repeated_command_of_the_followed_writer_is_refused():
    gate = CommandGate()
    seq = run_controller(gate, 3)
    gate.expect(stamp(3))
    assert answer(gate, 3, seq) == []
    assert gate.offer(BLADE, stamp(3), (0.2, 0.0), seq + 1) != []
    assert gate.take()[0] == 0.05


def test_without_sequence_numbers_the_first_command_of_a_tick_is_kept():
    gate = CommandGate()
    gate.expect(stamp(0))
    assert gate.offer(BLADE, stamp(0), (0.3, 0.0), None) == []
    assert gate.offer(BLADE, stamp(0), (0.05, 0.0), 0) != []
    assert gate.offer(CHASSIS, stamp(0), (0.5,)) == []
    assert gate.take() == (0.3, 0.0, 0.5)


def test_an_intruder_copy_carrying_the_controllers_own_sequence_number_is_replaced_by_the_controllers():
    """Tick 1: the intruder's copy arrives first with sequence number 2, which continues the
    controller's counter (1 at tick 0) exactly as the controller's own command of tick 1 does.
    Counters cannot tell the two apart; the values can: the copy's subnormal is no command, so
    the controller's replaces it, and until then the gate says the tick is not to be trusted."""
    gate = CommandGate()
    seq = run_controller(gate, 1)
    gate.expect(stamp(1))
    assert gate.offer(BLADE, stamp(1), (0.06, 0.0), seq) == []  # the controller's blade command first
    assert gate.offer(CHASSIS, stamp(1), (5e-324,), seq) == []  # taken: it continues the counter
    assert gate.complete and not gate.plausible and not gate.ready  # complete, but not to be stepped yet
    warnings = gate.offer(CHASSIS, stamp(1), (0.4,), seq)  # the controller's, same number
    assert [kind for kind, _ in warnings] == [f"{CHASSIS}:writer:same_sequence"]
    assert "replaced" in warnings[0][1] and str(seq) in warnings[0][1]
    assert gate.plausible and gate.ready
    assert gate.take() == (0.06, 0.0, 0.4)
    gate.expect(stamp(2))  # and the controller is followed on: its counter continues
    assert answer(gate, 2, seq + 1, u_zr=0.07, u_x=0.45) == []
    assert gate.take() == (0.07, 0.0, 0.45)


def test_a_second_claim_of_a_taken_sequence_number_does_not_replace_a_plausible_command():
    gate = CommandGate()
    seq = run_controller(gate, 3)
    gate.expect(stamp(3))
    assert answer(gate, 3, seq, u_zr=0.05, u_x=0.4) == []
    for values in ((1e308,), (0.9,)):  # garbage, and a plausible value second: the first stays
        assert [k for k, _ in gate.offer(CHASSIS, stamp(3), values, seq)] == [f"{CHASSIS}:writer:same_sequence"]
    assert gate.ready and gate.take() == (0.05, 0.0, 0.4)
    assert gate.rejected == 2 and gate.sanitised == 0


def test_a_replaced_command_is_counted_as_the_one_applied():
    """The sanitised count follows the command applied: an out-of-range intruder copy that is
    replaced leaves no sanitised command behind, a replacement that is clamped counts."""
    gate = CommandGate()
    seq = run_controller(gate, 2)
    gate.expect(stamp(2))
    assert [k for k, _ in gate.offer(CHASSIS, stamp(2), (1e30,), seq)] == [f"{CHASSIS}:u_x:out_of_range"]
    assert gate.sanitised == 1
    gate.offer(CHASSIS, stamp(2), (0.45,), seq)
    assert gate.sanitised == 0 and gate.take()[2] == 0.45
    gate.expect(stamp(3))
    gate.offer(CHASSIS, stamp(3), (math.nan,), seq + 1)
    kinds = [k for k, _ in gate.offer(CHASSIS, stamp(3), (9.0,), seq + 1)]  # plausible, out of range: clamped
    assert kinds == [f"{CHASSIS}:writer:same_sequence", f"{CHASSIS}:u_x:out_of_range"] and gate.sanitised == 1
