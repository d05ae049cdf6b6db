"""The controller node with the force lift on (``force_lift_m_s`` > 0), over real DDS: a tick is
answered only once its twist, pose and /blade/force are all in, the blade command is the core's
for that force, its gain changes at run time, and switching it off at run time is refused."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import String

from anti_stall_controller.controller import AntiStallController, AntiStallGains
from soil_msgs_py import graph as G
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.episode import EpisodeMeta
from tests.anti_stall_controller.controller_probe import FIRST, send_until_answered, tick_stamp as _tick
from tests.ros_probe import call_service, NodeProc, RosProbe, next_domain_id

pytestmark = pytest.mark.live

TWIST, POSE, FORCE, BLADE = T.CHASSIS_TWIST.name, T.CHASSIS_POSE.name, T.BLADE_FORCE.name, T.BLADE_CMD.name
DEPTH, SPEED = 0.2, 0.5


@pytest.mark.timeout(120)
def test_the_force_lift_joins_the_force_by_stamp_and_lifts_like_the_core(tmp_path):
    domain = next_domain_id()
    classes = M.ros_message_classes()
    meta = EpisodeMeta("Clay", 80.0, "fee", 3, SPEED, DEPTH, 30.0, source="test")
    gains = AntiStallGains(force_lift_m_s=2.0, force_lift_share=1.0)
    core = AntiStallController(gains, SPEED, DEPTH)  # what the node must answer
    with RosProbe(domain) as probe:
        probe.subscribe(BLADE, T.BLADE_CMD.msgtype)
        status = probe.publisher(G.SIM_STATUS_TOPIC, G.STRING_MSGTYPE)
        pubs = {t: probe.publisher(t, T.TOPICS_BY_NAME[t].msgtype) for t in (TWIST, POSE, FORCE)}
        ctl = NodeProc("anti_stall_controller", ["--ros-args", "-p", "force_lift_m_s:=2.0"], domain, tmp_path)
        try:
            probe.wait_for(lambda: all(p.get_subscription_count() >= 1 for p in (status, *pubs.values()))
                           and probe.matched_publishers(BLADE) >= 1, 30, "controller endpoints")
            status.publish(String(data=G.EpisodeEvent(G.EVENT_EPISODE_START, 0, meta.name, meta, FIRST,
                                                      planned_ticks=1800).to_json()))

            def answers() -> dict[int, float]:
                return {s: v[1] for s, v in (M.parse_message(BLADE, m) for m in probe.messages(BLADE))}

            def send(k: int, topics, force_n=(0.0, 0.0)) -> None:
                values = {TWIST: [SPEED * 0.9, 0.0], POSE: [0.0, 0.0], FORCE: list(force_n)}
                for t in topics:
                    pubs[t].publish(M.build_message(classes, t, _tick(k), values[t]))

            def answered(k: int, force_n) -> float:
                """Tick k's u_za, its state sent until answered."""
                send_until_answered(probe, lambda: send(k, (TWIST, POSE, FORCE), force_n), lambda: _tick(k) in answers(),
                                    f"the answer to tick {k}")
                return answers()[_tick(k)]

            forces = [(0.0, 0.0), (30e3, 5e3), (26e3, 0.0), (10e3, 36e3), (12e3, 0.0)]
            for k, f in enumerate(forces):
                want = core.step(SPEED * 0.9, 0.0, np.array(f)).u_za[0]
                assert answered(k, f) == want, (k, f)
            assert core.depth_offset_m[0] > 0.01  # the force beyond the limits lifted the blade
            # twist and pose alone are not a tick with the lift on: no answer until its force comes
            k = len(forces)
            send(k, (TWIST, POSE))
            with pytest.raises(AssertionError):
                probe.wait_for(lambda: _tick(k) in answers(), 1.5, "no answer without the force")
            send(k, (FORCE,), (34e3, 0.0))
            probe.wait_for(lambda: _tick(k) in answers(), 10, "the answer once the force is in")
            lifted = core.step(SPEED * 0.9, 0.0, np.array([34e3, 0.0])).u_za[0]
            assert answers()[_tick(k)] == lifted  # that force's lift, not an answer without it
            assert lifted > AntiStallController(gains, SPEED, DEPTH).step(SPEED * 0.9, 0.0, np.zeros(2)).u_za[0]
            # at run time the gain changes, but the lift is not switched off (a tick would wait for
            # a force no longer joined, or the other way round); a bad share is refused
            client = AsyncParameterClient(probe.node, "anti_stall_controller")
            assert client.wait_for_services(timeout_sec=20)
            for name, value, says in (("force_lift_share", 0.0, "force_lift_share"),
                                      ("force_lift_m_s", 0.0, "would switch the force lift off"),
                                      ("inputs_wait_s", -1.0, "['inputs_wait_s'] can only be set at start-up")):
                bad = call_service(lambda: client.set_parameters([Parameter(name, value=value)]))
                assert not bad.results[0].successful and says in bad.results[0].reason, bad.results[0].reason
            ok = call_service(lambda: client.set_parameters([Parameter("force_lift_m_s", value=3.0)]))
            assert all(r.successful for r in ok.results)
            core.set_gains(force_lift_m_s=3.0)
            assert answered(k + 1, (36e3, 0.0)) == core.step(SPEED * 0.9, 0.0, np.array([36e3, 0.0])).u_za[0]
        finally:
            ctl.stop()
        out = ctl.output
    assert "force lift on: each tick is answered once /chassis/twist, /chassis/pose, /blade/force are in" in out, out
