"""Shared pytest configuration for the insitu-soil test suite.

Tests live in one folder per package (``tests/<package>/``), the cross-package graph tests in
``tests/graph/`` and the workspace checks in ``tests/workspace/``. Helpers shared by several
folders sit here (``tests.ros_probe``, ``tests.bag_fixtures``, ``tests.sim_plugins``); every
folder is a package, so a test folder never shadows the project package it is named after.

DDS stays on loopback for every test: the test process itself (which hosts probe nodes)
and every node it starts get ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; the deprecated
ROS_LOCALHOST_ONLY, which would override it, is removed.
"""
import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long-running test (deselect with -m 'not slow')")


def pytest_sessionstart(session):
    """The simulator's compiled kernel in Numba's cache before any test starts a node: a node
    compiling it at its first tick (~10 s on a fresh clone) would miss its first deadlines."""
    from soil_sim_node.warm_up import warm_up

    warm_up()
