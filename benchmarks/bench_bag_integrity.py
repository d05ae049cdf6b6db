"""What a bag read costs before and after bags carried CRCs and QoS. Prints figures; asserts nothing.

    .venv/bin/python benchmarks/bench_bag_integrity.py [--reads 10] [--bags 100]

Side by side in one run, alternated; CPU time of this process (``time.process_time``: reading
is single-threaded, and on a shared machine wall time mostly measures the other load); the
ratios are the figures. "before": a bag as committed in bags/samples (rosbags' writer: one
chunk, CRC 0, no QoS) read with the CRC check off and rosbags' YAML parser forced to pure
Python (as before ``ruamel.yaml.clib`` was pinned). "after": the same episode rewritten by
today's writer (CRCs, QoS, 64 KiB chunks) read with the check on and the libyaml parser.
The middle rows separate the two effects. Then ``read_dataset`` over ``--bags`` bags, before
(copies of the committed bag) and after (rewritten bags).
"""
from __future__ import annotations

import argparse
import gc
import logging
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import ruamel.yaml.main

from soil_bag_tools import bag_io

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / "bags" / "samples" / "default_loam_id060_v0.50_d0.200_s7"
_CHECK, _CPARSER = bag_io.check_integrity, ruamel.yaml.main.CParser


def mode(check: bool, c_yaml: bool) -> None:
    bag_io.check_integrity = _CHECK if check else (lambda bag: None)
    ruamel.yaml.main.CParser = _CPARSER if c_yaml else None


def timed(fn, *args) -> float:
    """CPU seconds of ``fn(*args)``, garbage from the previous call collected first."""
    gc.collect()
    t0 = time.process_time()
    fn(*args)
    return time.process_time() - t0


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--reads", type=int, default=10, help="reads per row (median reported)")
    p.add_argument("--bags", type=int, default=100, help="bags in each dataset directory")
    opts = p.parse_args()
    logging.getLogger("soil_bag_tools.bag_io").setLevel(logging.ERROR)  # the no-CRC warning, once per bag
    if _CPARSER is None:
        raise SystemExit("ruamel.yaml.clib is not installed (make venv)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        new = bag_io.write_episode(tmp / SAMPLE.name, bag_io.read_episode(SAMPLE))
        rows = {  # label: (bag, check, libyaml)
            "before: committed bag, no check, pure-Python YAML": (SAMPLE, False, False),
            "committed bag, no check, libyaml": (SAMPLE, False, True),
            "committed bag (no CRCs), check on, libyaml": (SAMPLE, True, True),
            "new bag (CRCs, QoS), check off, libyaml": (new, False, True),
            "after: new bag, check on, libyaml": (new, True, True),
            "new bag, check on, pure-Python YAML": (new, True, False),
        }
        times: dict[str, list[float]] = {k: [] for k in rows}
        for _ in range(opts.reads):
            for label, (bag, check, c_yaml) in rows.items():
                mode(check, c_yaml)
                times[label].append(timed(bag_io.read_episode, bag))
        base = statistics.median(times[next(iter(rows))])
        print(f"{'read_episode, one 600-tick bag':52s} {'CPU ms':>9s} {'vs before':>9s}")
        for label, t in times.items():
            print(f"{label:52s} {statistics.median(t) * 1e3:9.1f} {statistics.median(t) / base:9.2f}")

        before, after = tmp / "before", tmp / "after"
        for i in range(opts.bags):
            shutil.copytree(SAMPLE, before / f"bag_{i:03d}")
            bag_io.write_episode(after / f"bag_{i:03d}", bag_io.read_episode(new))
        runs: dict[str, list[float]] = {"before": [], "after": []}
        for _ in range(2):
            mode(False, False)
            runs["before"].append(timed(bag_io.read_dataset, before))
            mode(True, True)
            runs["after"].append(timed(bag_io.read_dataset, after))
        b, a = min(runs["before"]), min(runs["after"])
        print(f"read_dataset, {opts.bags} bags: before {b:.1f} s, after {a:.1f} s CPU (x{a / b:.2f}; best of 2, alternated)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
