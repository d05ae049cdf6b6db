"""Shared pytest configuration for the insitu-soil test suite.

DDS stays on loopback for every test: the test process itself (which hosts probe nodes)
and every node it starts get ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; the deprecated
ROS_LOCALHOST_ONLY, which would override it, is removed.
"""
import os

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long-running test (deselect with -m 'not slow')")
