"""Shared pytest configuration for the insitu-soil test suite.

Tests live in one folder per package (``tests/<package>/``), the cross-package graph tests in
``tests/graph/`` and the workspace checks in ``tests/workspace/``. Helpers shared by several
folders sit here (``tests.ros_probe``, ``tests.bag_fixtures``, ``tests.sim_plugins``); every
folder is a package, so a test folder never shadows the project package it is named after.

``make test`` runs the suite in worker processes (pytest-xdist, ``-n``; the scheduler below):
the tests of a module marked ``live`` run one after another in one of two lanes: the graphs'
(nodes over DDS) and the clusters' (a Ray cluster or torchrun), so two graphs never run at once
and two clusters never race for one port, while a graph may run beside a cluster as it does
beside the other worker's tests; every other module goes to a worker whole, so its module
fixtures (the discrepancy datasets) are made once. A test of a module that imports rclpy or the
DDS / Ray test helpers, or runs torchrun, without the mark fails with that reason, and so does
one of a module that starts both a graph and a cluster (it belongs to neither lane: split it).

DDS stays on loopback for every test: the test process itself (which hosts probe nodes)
and every node it starts get ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; the deprecated
ROS_LOCALHOST_ONLY, which would override it, is removed.
"""
import functools
import os
import re
import signal
from pathlib import Path

import pytest

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)


def pytest_configure(config):
    # A suite started in the background (`make test &`, a CI runner's non-interactive shell) has
    # Ctrl-C ignored, and every process it starts inherits that: Python keeps an ignored SIGINT, so
    # the tests that send a tool Ctrl-C found it ignoring it (a tool "unanswered" by Ctrl-C in CI, the
    # cause not found for two sessions). A foreground terminal's disposition: any handler here is
    # reset to the default at each child's exec, where Python installs its own again.
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    config.addinivalue_line("markers", "slow: long-running test (deselect with -m 'not slow')")
    config.addinivalue_line("markers", "live: starts ROS nodes over DDS, a Ray cluster or torchrun "
                                       "(make test runs these one at a time per lane: graphs, clusters)")


LIVE_SCOPE = "live"  # the graphs' lane
CLUSTER_SCOPE = "live-clusters"  # the clusters' lane
# What only a live module imports (at its top or in a test) or runs. A graph: rclpy, the DDS
# domain leases and probe nodes, a leased domain. A cluster: the Ray probe, a Ray session,
# torchrun (python -m torch.distributed.run).
DDS_HELPERS = re.compile(r"^\s*(import rclpy|from rclpy[ .]|from tests(\.| import )(ros_domains|ros_probe|hostile)\b)"
                         r"|next_domain_id\(", re.MULTILINE)
CLUSTER_HELPERS = re.compile(r"^\s*from tests(\.| import )ray_probe\b|ray_session\(|ray\.init\("
                             r"|-m torch\.distributed\.run\b", re.MULTILINE)
LIVE_MARK = re.compile(r"\bpytest\.mark\.live\b")


@functools.lru_cache(maxsize=None)
def _source(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def uses_dds_helpers(path: Path) -> bool:
    """True if the test module at ``path`` imports rclpy or a DDS helper, or leases a domain."""
    return DDS_HELPERS.search(_source(path)) is not None


def uses_cluster_helpers(path: Path) -> bool:
    """True if the test module at ``path`` starts a Ray session, reads the Ray probe or runs torchrun."""
    return CLUSTER_HELPERS.search(_source(path)) is not None


def uses_live_helpers(path: Path) -> bool:
    """True if the test module at ``path`` imports rclpy or a DDS / Ray helper, or runs torchrun."""
    return uses_dds_helpers(path) or uses_cluster_helpers(path)


def is_live_module(path: Path) -> bool:
    """True if the test module at ``path`` is marked live or uses the live helpers (all the
    scheduler, which sees only test ids, can tell; ``pytest_runtest_setup`` makes sure the mark
    is where it must be)."""
    return LIVE_MARK.search(_source(path)) is not None or uses_live_helpers(path)


def live_lane(path: Path) -> str:
    """The lane of a live module: the clusters' if it starts only clusters, else the graphs' (a
    module marked live that uses neither kind of helper, e.g. one that runs soil_launch, too)."""
    return CLUSTER_SCOPE if uses_cluster_helpers(path) and not uses_dds_helpers(path) else LIVE_SCOPE


def pytest_runtest_setup(item):
    """Fail a test of a module that uses the live helpers without the ``live`` mark (see above;
    a test failure, not a collection error, so that xdist's workers report it with its reason)."""
    path = Path(item.path)
    if item.get_closest_marker("live") is None and uses_live_helpers(path):
        pytest.fail(f"{item.module.__name__} imports rclpy or the DDS / Ray test helpers, or runs torchrun, but is not "
                    "marked 'live' (add pytestmark = pytest.mark.live): live tests run one at a time", pytrace=False)
    if uses_dds_helpers(path) and uses_cluster_helpers(path):
        pytest.fail(f"{item.module.__name__} starts both DDS graphs and a Ray cluster or torchrun: graphs and clusters "
                    "each run one at a time in a lane of their own (tests/conftest.py); put its cluster tests in "
                    "a module of their own", pytrace=False)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """pytest-xdist's scope scheduling with three kinds of scope: the graphs' live modules are one
    scope and the clusters' another (each lane's tests run one after another in one worker), every
    other module its own (its module fixtures made once). (xdist's ``--dist loadgroup`` would say
    it with marks, but it renames test ids through an attribute pytest 9 no longer reads: its
    groups are ignored.)"""
    if config.getvalue("dist") != "load":  # a --dist the user chose (load: -n's default)
        return None
    from xdist.scheduler import LoadScopeScheduling

    def scope(module: str) -> str:
        for base in (config.rootpath, config.invocation_params.dir):  # test ids are relative to one of them
            if (base / module).is_file():
                return live_lane(base / module) if is_live_module(base / module) else module
        return module

    class LiveOneAtATime(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return scope(nodeid.split("::", 1)[0])

    return LiveOneAtATime(config, log)


def pytest_sessionstart(session):
    """The simulator's compiled kernel in Numba's cache before any test starts a node: a node
    compiling it at its first tick (~10 s on a fresh clone) would miss its first deadlines."""
    from soil_sim_node.warm_up import ready

    ready()
