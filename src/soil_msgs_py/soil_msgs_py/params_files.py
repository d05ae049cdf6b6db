"""Which sections of a ROS 2 params file apply to a node, by rcl's rules (no rclpy).

A node reads them through rcl; the launcher, which starts the nodes, reads the same sections to
know what a node was given (the simulator's world, the estimator's checkpoint), and a node
warns when none of a file's sections is its own.
"""
from __future__ import annotations

import re

from .yaml_file import read_yaml


def read_params_file(path) -> dict:
    """The sections of the ROS params file ``path``: its top-level mapping ({} if it holds none).
    ValueError naming the file for one that is missing, unreadable, not UTF-8 (a binary file had
    ended the launcher in a UnicodeDecodeError) or not YAML (``yaml_file.read_yaml``)."""
    data = read_yaml(path, "params file")
    return data if isinstance(data, dict) else {}


def section_matches(key: str, fully_qualified_name: str) -> bool:
    """Whether a params file's section key applies to the node, by rcl's rule: the key (a
    leading ``/`` optional) as a pattern in which ``/**`` stands for any number of namespace
    tokens, none included (``/**/node`` applies to the root-namespace ``/node``), and ``/*``
    for exactly one."""
    pattern = re.escape("/" + key.strip().lstrip("/"))
    pattern = pattern.replace(r"/\*\*", r"(?:/\w+)*").replace(r"/\*", r"(?:/\w+)")
    return re.fullmatch(pattern, "/" + fully_qualified_name.strip().lstrip("/")) is not None


def node_parameters(sections: dict, fully_qualified_name: str) -> list[dict]:
    """The ``ros__parameters`` mappings of a params file's parsed YAML that apply to the node, in
    file order (a later one wins, as in rcl); nested namespace maps (``ns: {node: {...}}``) are
    read as the key ``ns/node``."""
    out = []

    def walk(data: dict, prefix: str) -> None:
        for key, value in data.items():
            if not isinstance(value, dict):
                continue
            path = f"{prefix}/{str(key).strip('/')}" if prefix else str(key)
            if "ros__parameters" in value:
                params = value["ros__parameters"]
                if isinstance(params, dict) and section_matches(path, fully_qualified_name):
                    out.append(params)
            else:
                walk(value, path)

    walk(sections, "")
    return out
