"""Compile, or load from Numba's cache, every entry point of the simulator's kernel, once.

On a fresh machine the kernel compiles in ~10 s (more on a busy one). A node that did that at
its first tick would miss its first deadlines, so: ``make venv`` runs this module after
installing, the simulator node calls ``ready`` before its first episode, as does every compiled
simulator as it is made (once per process), and the test suite once per session. With the cache
in place it takes ~0.6 s.

    python -m soil_sim_node.warm_up
"""
from __future__ import annotations

import time

from soil_msgs_py.interrupts import interrupts_deferred
from soil_msgs_py.params import SAMPLE_RATE_HZ

from .rollout import run_episodes
from .simulator import EpisodeSpec, SimConfig, SoilSimulator


def _no_force(state):  # noqa: ARG001 - a plugin, to compile the kernel's two halves
    return 0.0, 0.0


def warm_up() -> float:
    """Run each compiled path once (whole episodes, the node's tick, the plugin halves); the wall s it took."""
    t0 = time.perf_counter()
    spec = EpisodeSpec("Loam", 50.0, 0.5, 0.1, seed=0, duration_s=2 / SAMPLE_RATE_HZ)
    run_episodes(SimConfig(world_mode="fee"), [spec])
    SoilSimulator(SimConfig(world_mode="fee"), [spec]).step(0.0, 0.0, 0.5)
    SoilSimulator(SimConfig(world_mode="fee", plugins=(f"{__name__}:_no_force",)), [spec]).step(0.0, 0.0, 0.5)
    return time.perf_counter() - t0


_READY = {"done": False}


def ready() -> float:
    """``warm_up`` once per process (every compiled simulator calls it as it is made), with Ctrl-C
    and SIGTERM deferred meanwhile; the wall s it took (0 once done). Why: Numba loads its cache
    through ctypes callbacks, where the KeyboardInterrupt a handler raises is printed as "Exception
    ignored" and lost, and a second Ctrl-C then met LLVM half-loaded: a tool stopped twice as its
    first cut began crashed (SIGSEGV in libpython, an outside tester's, three times). A stop during
    it waits for it: ~0.6 s with the cache, a first compile ~10 s (``make venv`` does that)."""
    if _READY["done"]:
        return 0.0
    _READY["done"] = True  # (warm_up's own simulators call this again)
    with interrupts_deferred():
        return warm_up()


def main() -> int:
    print(f"soil_sim_node: simulator kernel ready in {ready():.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
