"""Online estimator benchmarks (issue: online PINN estimator). Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_estimator.py
    .venv/bin/python benchmarks/bench_estimator.py --steps 5000 --seconds 40 --json /tmp/bench_estimator.json

1. Model step latency at batch 1, in this process, one torch thread, windows from a real
   sample bag (target p99 < 2 ms): the raw model forward; ``OnlineEstimator.estimate()``
   (ring buffer -> tensors -> model -> values); one whole tick of the core (7 ``add()`` of
   built rclpy messages, the last of which releases the sample and runs the estimate), back
   to back and then paced at 60 Hz (``--paced-ticks``; what the node sees: a step every
   16.7 ms runs with cold caches and is about twice as slow as back to back); and what the
   node adds per valid estimate (building its two output messages).
2. Sample-in -> estimate-out latency through DDS (target p99 < 5 ms): the real
   ``pinn_estimator`` node in its own process; an in-process probe publishes each tick's 7
   input messages at 60 Hz (the bag looped, stamps always increasing, an ``episode_start``
   on ``/sim/status`` at each loop, so each loop refills the window: 59 invalid estimates).
   Latency = perf_counter at publishing the LAST input message of a tick -> perf_counter
   at receiving the ``/soil/estimate`` with that stamp. The first ``--warmup`` seconds of the
   stream are excluded; figures are over valid estimates of the rest.
   Arrival spacing = wall time between the estimates of two consecutive ticks (both valid,
   measured): how evenly the 60 Hz estimates come out (the node test checks one estimate
   per tick, stamps on the 60 Hz grid).
3. CPU of the node over the measured part of the same stream (utime + stime from
   /proc/<pid>/stat, % of one core) and its RSS (VmRSS, VmHWM from /proc/<pid>/status).

``--seconds`` is the length of the 60 Hz stream (warm-up included; the default gives 20 s
of valid estimates after the warm-up); the whole run takes about ``--seconds`` + 12 s (micro benchmarks, node start-up, shutdown). Loopback DDS only,
on its own ROS_DOMAIN_ID (--domain-id; default $ROS_DOMAIN_ID, else 61); the node process is always stopped.
"""
from __future__ import annotations

import argparse
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from soil_bringup.launch import add_domain_id_option  # (imports no rclpy: fine before the DDS settings below)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bag", default="bags/samples/default_loam_id060_v0.50_d0.200_s7",
                   help="episode bag whose rows feed the estimator")
    p.add_argument("--steps", type=int, default=2000, help="timed steps per micro benchmark (after warm-up)")
    p.add_argument("--warmup-steps", type=int, default=200)
    p.add_argument("--paced-ticks", type=int, default=300, help="core ticks timed at 60 Hz pacing (not back to back)")
    p.add_argument("--seconds", type=float, default=24.0, help="length of the 60 Hz DDS stream, warm-up included")
    p.add_argument("--warmup", type=float, default=2.0, help="stream seconds excluded from latency and CPU figures")
    add_domain_id_option(p, 61)
    p.add_argument("--no-dds", action="store_true", help="micro benchmarks only")
    p.add_argument("--json", type=Path, default=None, help="also write the figures to this JSON file")
    return p


# DDS on loopback and on our domain, set before rclpy (or any ROS package) is imported.
_early, _ = _parser().parse_known_args()
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)
os.environ["ROS_DOMAIN_ID"] = str(_early.domain_id)

import numpy as np  # noqa: E402
import torch  # noqa: E402

from pinn_estimator.checkpoint import DEFAULT_CHECKPOINT, load_model  # noqa: E402
from pinn_estimator.online import INPUT_TOPICS, OnlineEstimator  # noqa: E402
from soil_msgs_py import graph as G  # noqa: E402
from soil_msgs_py import strict_json  # noqa: E402
from soil_msgs_py import messages as M  # noqa: E402
from soil_msgs_py import topics as T  # noqa: E402
from soil_bag_tools.bag_io import read_episode  # noqa: E402
from soil_msgs_py.params import SAMPLE_RATE_HZ as RATE_HZ, WINDOW_SAMPLES  # noqa: E402
from soil_msgs_py.params import tick_stamp_ns as stamp_of  # noqa: E402
from graph_procs import CLK_TCK, cpu_seconds  # noqa: E402
from soil_bringup.launch import loopback_env  # noqa: E402
from soil_discrepancy.provenance import cpu_model  # noqa: E402

BIN = Path(sys.executable).parent
REPO = Path(__file__).resolve().parent.parent
VALID = T.ESTIMATE_FIELDS.index("valid")
STRETCHES = T.ESTIMATE_FIELDS.index("fused_stretches")


def stats_ms(samples_s) -> dict:
    """p50/p99/max/mean [ms] of durations in seconds."""
    a = np.asarray(samples_s, dtype=np.float64) * 1e3
    if not len(a):
        return {"n": 0, "p50_ms": None, "p99_ms": None, "max_ms": None, "mean_ms": None}
    return {"n": int(len(a)), "p50_ms": round(float(np.percentile(a, 50)), 3),
            "p99_ms": round(float(np.percentile(a, 99)), 3), "max_ms": round(float(a.max()), 3),
            "mean_ms": round(float(a.mean()), 3)}


def fmt(s: dict) -> str:
    if not s["n"]:
        return "no samples"
    return (f"p50 {s['p50_ms']:7.3f}  p99 {s['p99_ms']:7.3f}  max {s['max_ms']:7.3f}  "
            f"mean {s['mean_ms']:7.3f} ms  (n={s['n']})")


def machine() -> dict:
    return {"cores": os.cpu_count(), "cpu": cpu_model(), "torch": str(torch.__version__), "python": platform.python_version(),
            "loadavg": os.getloadavg()}


# ------------------------------------------------------------------ 1. in-process micro benchmarks

def bench_core(ep, steps: int, warmup: int, paced: int) -> dict[str, dict]:
    torch.set_num_threads(1)
    model, _ = load_model(DEFAULT_CHECKPOINT)
    model.eval()
    n = len(ep)
    starts = range(0, n - WINDOW_SAMPLES + 1)
    obs_w = torch.as_tensor(np.stack([ep.observations[i:i + WINDOW_SAMPLES] for i in starts]), dtype=torch.float32)
    known_w = torch.as_tensor(np.stack([ep.known[i + WINDOW_SAMPLES - 1] for i in starts]), dtype=torch.float32)
    clock = time.perf_counter
    out: dict[str, dict] = {}

    # raw model forward, batch 1
    times = []
    with torch.inference_mode():
        for s in range(warmup + steps):
            i = s % len(obs_w)
            o, k = obs_w[i:i + 1], known_w[i:i + 1]
            t0 = clock()
            model(o, k)
            dt = clock() - t0
            if s >= warmup:
                times.append(dt)
    out["model_forward"] = stats_ms(times)

    # OnlineEstimator.estimate(): ring buffer -> tensors -> model -> values (one new sample per step)
    est = OnlineEstimator(model, lambda e: None)
    for i in range(WINDOW_SAMPLES):
        est.buffer.push(ep.observations[i], ep.known[i])
    times, bad = [], 0
    for s in range(warmup + steps):
        r = (WINDOW_SAMPLES + s) % n
        est.buffer.push(ep.observations[r], ep.known[r])
        t0 = clock()
        e = est.estimate(stamp_of(s))
        dt = clock() - t0
        bad += not e.valid
        if s >= warmup:
            times.append(dt)
    out["estimate"] = stats_ms(times) | {"invalid": bad}

    # one tick of the core: 7 add() of rclpy messages; the last releases the sample -> estimate -> publish
    classes = M.ros_message_classes()
    rows = {t: M.topic_rows(ep, t).tolist() for t in INPUT_TOPICS}
    published = []
    est = OnlineEstimator(model, published.append)
    ticks = WINDOW_SAMPLES + warmup + steps
    times, updated = [], []
    for k in range(ticks):
        msgs = [(t, M.build_message(classes, t, stamp_of(k), rows[t][k % n])) for t in INPUT_TOPICS]
        before = len(published)
        t0 = clock()
        for t, msg in msgs:
            est.add(t, msg)
        dt = clock() - t0
        if k >= WINDOW_SAMPLES + warmup:
            times.append(dt)
            # a new stretch in the published estimate: the fused posterior was updated in this tick
            updated.append(before > 0 and len(published) > before
                           and published[-1]["fused_stretches"] != published[before - 1]["fused_stretches"])
    c = est.counters
    upd = np.asarray(updated, dtype=bool)
    out["tick_core_no_update"] = stats_ms(np.asarray(times)[~upd])
    out["tick_core_update"] = stats_ms(np.asarray(times)[upd])
    out["tick_core"] = stats_ms(times) | {"estimates": c.estimates, "invalid": c.invalid,
                                          "expected_estimates": ticks - (WINDOW_SAMPLES - 1),
                                          "last_stamp_ok": bool(published and published[-1].stamp_ns == stamp_of(ticks - 1))}

    # the same tick paced at 60 Hz, as the node runs it: caches and CPU are cold between ticks
    times = []
    t_next = clock()
    for k in range(ticks, ticks + paced):
        msgs = [(t, M.build_message(classes, t, stamp_of(k), rows[t][k % n])) for t in INPUT_TOPICS]
        t_next += 1.0 / RATE_HZ
        time.sleep(max(0.0, t_next - clock()))
        t0 = clock()
        for t, msg in msgs:
            est.add(t, msg)
        times.append(clock() - t0)
    out["tick_core_60hz"] = stats_ms(times)

    # what the node adds per valid estimate: building /soil/estimate and /soil/estimate/force
    times = []
    for s in range(warmup + steps):
        e = published[WINDOW_SAMPLES + s % (len(published) - WINDOW_SAMPLES)]
        t0 = clock()
        M.make_labelled(classes, e.stamp_ns, T.ESTIMATE_FIELDS, e.values)
        M.build_message(classes, T.BLADE_FORCE.name, e.stamp_ns, [e["f_x_hat"], e["f_z_hat"]])
        dt = clock() - t0
        if s >= warmup:
            times.append(dt)
    out["output_msgs"] = stats_ms(times)
    return out


# ------------------------------------------------------------------ 2./3. through DDS, node in its own process


def machine_cpu_seconds() -> float:
    """CPU seconds all cores spent busy since boot (/proc/stat: everything but idle and iowait)."""
    v = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(v[:8]) - v[3] - v[4]) / CLK_TCK


def self_cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system


def proc_status_kb(pid: int, key: str) -> int | None:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return None


class Probe:
    """rclpy participant in its own context: publishes the inputs, records estimate arrivals."""

    def __init__(self, domain_id: int):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import String

        from soil_msgs_py.ros_adapter import init_context, message_class, topic_qos

        self.rclpy = rclpy
        self.String = String
        self.context = init_context(domain_id)
        self.node = rclpy.create_node("bench_estimator_probe", context=self.context)
        self.pubs = [self.node.create_publisher(message_class(T.TOPICS_BY_NAME[t].msgtype), t, topic_qos(t))
                     for t in INPUT_TOPICS]
        self.status_pub = self.node.create_publisher(String, G.SIM_STATUS_TOPIC, topic_qos(G.SIM_STATUS_TOPIC))
        self.received: list[tuple[float, object]] = []  # (perf_counter at callback, message)
        clock, append = time.perf_counter, self.received.append
        self.sub = self.node.create_subscription(message_class(T.ESTIMATE.msgtype), T.ESTIMATE.name,
                                                 lambda m: append((clock(), m)), topic_qos(T.ESTIMATE.name))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self.stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def matched(self) -> bool:
        return (all(p.get_subscription_count() >= 1 for p in self.pubs)
                and self.status_pub.get_subscription_count() >= 1 and self.sub.get_publisher_count() >= 1)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown(timeout_sec=1)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def start_node(domain_id: int, log) -> subprocess.Popen:
    return subprocess.Popen([str(BIN / "pinn_estimator"), "--ros-args"], env=loopback_env(domain_id), cwd=REPO,
                            stdout=log, stderr=subprocess.STDOUT)


def stop_node(proc: subprocess.Popen) -> int | None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)
    return proc.returncode


def bench_dds(ep, seconds: float, warmup_s: float, domain_id: int) -> dict:
    n_bag = len(ep)
    n_ticks = int(round(seconds * RATE_HZ))
    warm = int(round(warmup_s * RATE_HZ))
    period = 1.0 / RATE_HZ
    # Everything published is built before the stream: the probe does nothing but publish and sleep.
    classes = M.ros_message_classes()
    rows = {t: M.topic_rows(ep, t).tolist() for t in INPUT_TOPICS}
    ticks = [[M.build_message(classes, t, stamp_of(k), rows[t][k % n_bag]) for t in INPUT_TOPICS]
             for k in range(n_ticks)]
    loop_starts = list(range(0, n_ticks, n_bag))
    status = {}
    for k in loop_starts:
        ev = G.EpisodeEvent(event=G.EVENT_EPISODE_START, episode=k // n_bag, name=ep.meta.name, meta=ep.meta,
                            first_stamp_ns=stamp_of(k), planned_ticks=n_bag)
        status[k] = ev.to_json()

    log = tempfile.NamedTemporaryFile("w+", prefix="bench_estimator_node_", suffix=".log")
    proc = probe = None
    t_launch = time.perf_counter()
    try:
        proc = start_node(domain_id, log)
        probe = Probe(domain_id)
        t_end = time.monotonic() + 60
        while not probe.matched():
            if proc.poll() is not None or time.monotonic() > t_end:
                log.flush()
                log.seek(0)
                raise RuntimeError(f"estimator node not ready (exit code {proc.poll()}):\n{log.read()[-3000:]}")
            time.sleep(0.05)
        t_ready = time.perf_counter()
        time.sleep(0.5)  # the node's executor has started spinning
        rss_idle_kb = proc_status_kb(proc.pid, "VmRSS")

        String = probe.String
        pub_t = np.zeros(n_ticks)
        late = np.zeros(n_ticks)
        pubs = probe.pubs
        last = len(pubs) - 1
        clock = time.perf_counter
        t0 = clock() + 0.05
        cpu0 = wall0 = None
        for k in range(n_ticks):
            due = t0 + k * period
            if k in status:  # episode_start half a period ahead of the loop's first tick
                time.sleep(max(0.0, due - period / 2 - clock()))
                probe.status_pub.publish(String(data=status[k]))
            if k == warm:
                cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
                busy0, self0 = machine_cpu_seconds(), self_cpu_seconds()
            now = clock()
            if now < due:  # sleep, never spin: a spinning main thread would hold the GIL from the receiver
                time.sleep(due - now)
            msgs = ticks[k]
            for i in range(last):
                pubs[i].publish(msgs[i])
            t = clock()
            pubs[last].publish(msgs[last])
            pub_t[k] = t
            late[k] = t - due
        time.sleep(period)
        cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
        busy1, self1 = machine_cpu_seconds(), self_cpu_seconds()
        rss_kb, hwm_kb = proc_status_kb(proc.pid, "VmRSS"), proc_status_kb(proc.pid, "VmHWM")
        time.sleep(0.25)  # the last estimates
    finally:
        try:
            if probe is not None:
                probe.close()
        finally:
            rc = stop_node(proc) if proc is not None else None
        log.flush()
        log.seek(0)
        node_log = log.read()
        log.close()

    # match estimates to ticks by stamp
    k_of = {stamp_of(k): k for k in range(n_ticks)}
    recv_t = np.full(n_ticks, np.nan)
    valid = np.zeros(n_ticks, dtype=bool)
    stretches = np.full(n_ticks, np.nan)  # the fused posterior's stretch count each estimate carries
    dup = unknown = 0
    for t, msg in list(probe.received):
        stamp, values = M.parse_labelled(msg, T.ESTIMATE_FIELDS, T.ESTIMATE.name)
        k = k_of.get(stamp)
        if k is None:
            unknown += 1
            continue
        if not np.isnan(recv_t[k]):
            dup += 1
            continue
        recv_t[k] = t
        valid[k] = values[VALID] == 1.0
        stretches[k] = values[STRETCHES]
    got = ~np.isnan(recv_t)
    filling = np.array([k % n_bag < WINDOW_SAMPLES - 1 for k in range(n_ticks)])  # window refilling: invalid by design
    meas = np.arange(n_ticks) >= warm
    lat = recv_t - pub_t
    valid_m = meas & got & valid
    # the ticks whose estimate carries a new stretch: the node updated the fused posterior (every
    # 30 samples) before publishing it, on top of the model step (a stretch computed and then refused,
    # e.g. one the edge sank through, costs the same and counts as no update: rare on this cut)
    updated = np.zeros(n_ticks, dtype=bool)
    updated[1:] = got[1:] & got[:-1] & (stretches[1:] != stretches[:-1])
    wall = wall1 - wall0
    measured_ticks = np.flatnonzero(valid_m)
    next_tick = np.diff(measured_ticks) == 1
    spacing = np.diff(recv_t[measured_ticks])[next_tick]
    counters = next((line.strip() for line in reversed(node_log.splitlines()) if "estimates," in line), "")
    return {
        "node_ready_s": round(t_ready - t_launch, 2),
        "ticks": n_ticks, "warmup_ticks": warm, "loops": len(loop_starts),
        "estimates": int(got.sum()), "expected_estimates": n_ticks,
        "valid": int((got & valid).sum()), "expected_valid": int((~filling).sum()),
        "invalid": int((got & ~valid).sum()), "invalid_unexpected": int((got & ~valid & ~filling).sum()),
        "missing": int((~got).sum()), "duplicates": dup, "unknown_stamps": unknown,
        "measured": {"ticks": int(meas.sum()), "valid": int(valid_m.sum()),
                     "valid_seconds": round(float(valid_m.sum()) / RATE_HZ, 2),
                     "expected_valid": int((meas & ~filling).sum()), "wall_s": round(wall, 2),
                     "valid_per_s": round(float(valid_m.sum()) / wall, 2),
                     "estimates_per_s": round(float((meas & got).sum()) / wall, 2)},
        "latency_valid": stats_ms(lat[valid_m]),
        "latency_invalid": stats_ms(lat[meas & got & ~valid]),  # no model run: DDS + rclpy + core bookkeeping
        "latency_valid_no_update": stats_ms(lat[valid_m & ~updated]),
        "latency_posterior_update": stats_ms(lat[valid_m & updated]),
        "arrival_spacing": stats_ms(spacing),
        "publisher_late": stats_ms(late[meas]),
        "cpu_pct": round(100.0 * (cpu1 - cpu0) / wall, 1),
        # noise: what else kept the machine's cores busy meanwhile (% of one core)
        "probe_cpu_pct": round(100.0 * (self1 - self0) / wall, 1),
        "others_cpu_pct": round(100.0 * ((busy1 - busy0) - (cpu1 - cpu0) - (self1 - self0)) / wall, 1),
        "rss_mb": round(rss_kb / 1024, 1), "rss_idle_mb": round(rss_idle_kb / 1024, 1), "hwm_mb": round(hwm_kb / 1024, 1),
        "node_exit": rc, "node_counters": counters,
    }


def main() -> None:
    parser = _parser()
    args = parser.parse_args()
    if args.steps < 1 or args.paced_ticks < 1:
        parser.error("--steps and --paced-ticks must be >= 1")
    if not args.no_dds and args.seconds < args.warmup + 2:
        parser.error(f"--seconds {args.seconds} leaves less than 2 s after the {args.warmup} s warm-up")
    t_all = time.perf_counter()
    m = machine()
    print(f"machine: {m['cores']} cores ({m['cpu']}), torch {m['torch']}, python {m['python']}, "
          f"load average {m['loadavg'][0]:.2f}; ROS_DOMAIN_ID {args.domain_id} (loopback)")
    ep = read_episode(REPO / args.bag if not Path(args.bag).is_absolute() else args.bag)
    result: dict = {"machine": m, "bag": str(args.bag), "args": {k: str(v) for k, v in vars(args).items()}}

    print(f"== model step, batch 1, 1 torch thread, {args.steps} steps after {args.warmup_steps} warm-up "
          f"(target p99 < 2 ms); windows from {ep.meta.name}")
    core = bench_core(ep, args.steps, args.warmup_steps, args.paced_ticks)
    result["core"] = core
    labels = {"model_forward": "model forward", "estimate": "OnlineEstimator.estimate()",
              "tick_core": "tick: 7 add() + estimate", "tick_core_no_update": "  no posterior update",
              "tick_core_update": "  posterior updated", "tick_core_60hz": "same tick, paced at 60 Hz",
              "output_msgs": "node output msgs build"}
    for key, label in labels.items():
        print(f"{label:28s} {fmt(core[key])}")
    tc = core["tick_core"]
    print(f"{'':28s} tick core: {tc['estimates']}/{tc['expected_estimates']} valid estimates, {tc['invalid']} invalid "
          f"(window filling), last stamp ok: {tc['last_stamp_ok']}; estimate() invalid: {core['estimate']['invalid']}")

    if not args.no_dds:
        print(f"== sample-in -> estimate-out through DDS (target p99 < 5 ms): pinn_estimator node process, "
              f"{args.seconds:g} s at {RATE_HZ} Hz, first {args.warmup:g} s excluded")
        d = bench_dds(ep, args.seconds, args.warmup, args.domain_id)
        result["dds"] = d
        ms = d["measured"]
        print(f"node ready (matched) after {d['node_ready_s']} s; {d['ticks']} ticks in {d['loops']} bag loop(s) "
              f"(episode_start each loop -> {WINDOW_SAMPLES - 1} invalid while the window refills)")
        print(f"estimates received {d['estimates']}/{d['expected_estimates']}: valid {d['valid']}/{d['expected_valid']}, "
              f"invalid {d['invalid']} ({d['invalid_unexpected']} not explained by a window refill), missing "
              f"{d['missing']}, duplicates {d['duplicates']}, unknown stamps {d['unknown_stamps']}")
        print(f"measured: {ms['valid']}/{ms['expected_valid']} valid estimates = {ms['valid_seconds']} s of valid "
              f"estimates over {ms['wall_s']} s wall; {ms['valid_per_s']} valid estimates/s, "
              f"{ms['estimates_per_s']} estimates/s (all)")
        print(f"{'latency, valid estimates':28s} {fmt(d['latency_valid'])}")
        print(f"{'  no posterior update':28s} {fmt(d['latency_valid_no_update'])}")
        print(f"{'  posterior updated':28s} {fmt(d['latency_posterior_update'])}  (every 30 samples)")
        print(f"{'latency, invalid (no model)':28s} {fmt(d['latency_invalid'])}")
        print(f"{'probe publish lateness':28s} {fmt(d['publisher_late'])}")
        print(f"{'arrival spacing (16.667 nom.)':28s} {fmt(d['arrival_spacing'])}")
        print(f"== estimator node resources at {RATE_HZ} Hz, over the measured {ms['wall_s']} s")
        print(f"CPU {d['cpu_pct']:.1f} % of one core; RSS {d['rss_mb']} MB (idle before stream {d['rss_idle_mb']} MB, "
              f"peak {d['hwm_mb']} MB)")
        print(f"meanwhile: this probe process {d['probe_cpu_pct']:.1f} %, everything else on the machine "
              f"{d['others_cpu_pct']:.1f} % of one core (of {100 * (os.cpu_count() or 1)} %): noise on the figures above")
        print(f"node exit code {d['node_exit']}; node says: {d['node_counters'] or '(no counters line)'}")

    result["wall_s"] = round(time.perf_counter() - t_all, 1)
    print(f"total {result['wall_s']} s; load average now {os.getloadavg()[0]:.2f}")
    if args.json:
        args.json.write_text(strict_json.dumps(result, indent=2, default=str) + "\n")
        print(f"figures written to {args.json}")


if __name__ == "__main__":
    main()
