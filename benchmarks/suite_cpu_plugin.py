"""A pytest plugin for ``suite_cpu.py``: each test's wall time and CPU time (this process's and
its reaped children's ``getrusage``: the nodes, tools and worker pools a test starts and waits
for) appended as a tab-separated line to the file ``$SUITE_CPU_LOG`` names."""
from __future__ import annotations

import os
import resource
import time

import pytest


def _cpu_s() -> tuple[float, float]:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):  # noqa: ARG001 - pytest's hook signature
    wall0, (own0, children0) = time.perf_counter(), _cpu_s()
    yield
    own1, children1 = _cpu_s()
    with open(os.environ["SUITE_CPU_LOG"], "a", encoding="utf-8") as log:  # (one short line: appends do not interleave)
        log.write(f"{item.nodeid}\t{time.perf_counter() - wall0:.3f}\t{own1 - own0:.3f}\t{children1 - children0:.3f}\n")
