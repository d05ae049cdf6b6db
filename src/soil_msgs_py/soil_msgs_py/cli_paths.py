"""Output paths of the command-line tools, checked when the arguments are parsed (no ROS).

Why here: every tool that writes a report, a checkpoint or bags takes an ``--out``; checked only
when it writes, a path that cannot be written (an existing file where a directory is wanted, or
a directory where a file is) ends a run of minutes with a traceback and loses its work. As an
argparse ``type`` the tool refuses it before it starts, naming the flag and the path (exit 2).
"""
from __future__ import annotations

import argparse
from pathlib import Path


def output_dir(text: str) -> Path:
    """An ``--out`` directory: may exist (as a directory) or not yet; not an existing file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not a directory")
    if any(parent.exists() and not parent.is_dir() for parent in path.parents):
        raise argparse.ArgumentTypeError(f"{text!r}: a parent of it is a file, not a directory")
    return path


def output_file(text: str) -> Path:
    """An ``--out`` file: may exist (as a file, to be replaced) or not yet; not a directory."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a directory; give the file to write")
    if any(parent.exists() and not parent.is_dir() for parent in path.parents):
        raise argparse.ArgumentTypeError(f"{text!r}: a parent of it is a file, not a directory")
    return path
