"""Shared pytest configuration for the insitu-soil test suite.

Tests live in one folder per package (``tests/<package>/``), the cross-package graph tests in
``tests/graph/`` and the workspace checks in ``tests/workspace/``. Helpers shared by several
folders sit here (``tests.ros_probe``, ``tests.bag_fixtures``, ``tests.sim_plugins``); every
folder is a package, so a test folder never shadows the project package it is named after.

``make test`` runs the suite in worker processes (pytest-xdist, ``-n``; the scheduler below):
the tests of a module marked ``live`` (they start nodes over DDS, a Ray cluster or torchrun)
run one after another in one worker, so two graphs never run at once and two clusters never
race for one port (a graph still shares the cores with the other worker's tests); every other
module goes to a worker whole, so its module fixtures (the discrepancy datasets) are made once. A test of a module that imports rclpy or the DDS /
Ray test helpers, or runs torchrun, without the mark fails with that reason.

DDS stays on loopback for every test: the test process itself (which hosts probe nodes)
and every node it starts get ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; the deprecated
ROS_LOCALHOST_ONLY, which would override it, is removed.
"""
import functools
import os
import re
from pathlib import Path

import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long-running test (deselect with -m 'not slow')")
    config.addinivalue_line("markers", "live: starts ROS nodes over DDS, a Ray cluster or torchrun "
                                       "(make test runs these one at a time)")


LIVE_SCOPE = "live"
# What only a live module imports (at its top or in a test): rclpy, the DDS domain leases and
# probe nodes, the Ray probe; or what it runs: a leased domain, a Ray session, torchrun
# (python -m torch.distributed.run).
LIVE_HELPERS = re.compile(r"^\s*(import rclpy|from rclpy[ .]|from tests(\.| import )(ros_domains|ros_probe|ray_probe|hostile)\b)"
                          r"|next_domain_id\(|ray_session\(|ray\.init\(|-m torch\.distributed\.run\b", re.MULTILINE)
LIVE_MARK = re.compile(r"\bpytest\.mark\.live\b")


@functools.lru_cache(maxsize=None)
def _source(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def uses_live_helpers(path: Path) -> bool:
    """True if the test module at ``path`` imports rclpy or a DDS / Ray helper, or runs torchrun."""
    return LIVE_HELPERS.search(_source(path)) is not None


def is_live_module(path: Path) -> bool:
    """True if the test module at ``path`` is marked live or uses the live helpers (all the
    scheduler, which sees only test ids, can tell; ``pytest_runtest_setup`` makes sure the mark
    is where it must be)."""
    return LIVE_MARK.search(_source(path)) is not None or uses_live_helpers(path)


def pytest_runtest_setup(item):
    """Fail a test of a module that uses the live helpers without the ``live`` mark (see above;
    a test failure, not a collection error, so that xdist's workers report it with its reason)."""
    if item.get_closest_marker("live") is None and uses_live_helpers(Path(item.path)):
        pytest.fail(f"{item.module.__name__} imports rclpy or the DDS / Ray test helpers, or runs torchrun, but is not "
                    "marked 'live' (add pytestmark = pytest.mark.live): live tests run one at a time", pytrace=False)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """pytest-xdist's scope scheduling with two kinds of scope: every live module is one scope
    (``live``: its tests run one after another in one worker), every other module its own (its
    module fixtures made once). (xdist's ``--dist loadgroup`` would say it with marks, but it renames
    test ids through an attribute pytest 9 no longer reads: its groups are ignored.)"""
    if config.getvalue("dist") != "load":  # a --dist the user chose (load: -n's default)
        return None
    from xdist.scheduler import LoadScopeScheduling

    def live(module: str) -> bool:
        for base in (config.rootpath, config.invocation_params.dir):  # test ids are relative to one of them
            if (base / module).is_file():
                return is_live_module(base / module)
        return False

    class LiveOneAtATime(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return LIVE_SCOPE if live(module) else module

    return LiveOneAtATime(config, log)


def pytest_sessionstart(session):
    """The simulator's compiled kernel in Numba's cache before any test starts a node: a node
    compiling it at its first tick (~10 s on a fresh clone) would miss its first deadlines."""
    from soil_sim_node.warm_up import warm_up

    warm_up()
