"""Output paths of the command-line tools, checked when the arguments are parsed (no ROS).

Why here: every tool that writes a report, a checkpoint or bags takes an ``--out``; checked only
when it writes, a path that cannot be written (an existing file where a directory is wanted, or
a directory where a file is, a read-only place) ends a run of minutes with a traceback and loses
its work. As an
argparse ``type`` the tool refuses it before it starts, naming the flag and the path (exit 2).
``~`` is expanded. Give defaults as strings: argparse passes a string default through ``type``.
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path
from typing import Callable


def _checked(text: str, want_dir: bool) -> Path:
    if not text:  # Path("") is "." : an empty --out (an unset shell variable) would write into the cwd
        raise argparse.ArgumentTypeError("'' is empty; give a path" + (" (. for the current directory)" if want_dir else ""))
    path = Path(text).expanduser()
    try:
        if want_dir and path.exists() and not path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} exists and is not a directory")
        if not want_dir and path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} is a directory; give the file to write")
        if any(parent.exists() and not parent.is_dir() for parent in path.parents):
            raise argparse.ArgumentTypeError(f"{text!r}: a parent of it is a file, not a directory")
        _probe_writable(text, path if want_dir else path.parent)
    except OSError as err:  # e.g. a parent that cannot be searched
        raise argparse.ArgumentTypeError(f"{text!r}: {err.strerror or err}") from None
    return path


def _probe_writable(text: str, directory: Path) -> None:
    """Refuse ``text`` if nothing can be created in ``directory`` (or, where it does not exist
    yet, in its nearest existing ancestor, where the tool will create it): a read-only mount, no
    permission. A temporary file is made there and removed at once; nothing else is created."""
    existing = directory
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        with tempfile.TemporaryFile(dir=existing, prefix=".write_probe_"):
            pass
    except OSError as err:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be written: nothing can be created in {str(existing)!r} "
                                         f"({err.strerror or err})") from None


def input_text(text: str) -> str:
    """A path to read (a bag, a directory of bags, a checkpoint), as given: not empty. Path("")
    is ".", so an unset shell variable (``soil_bag_play "$BAG"``) would take the whole current
    directory: every bag under it replayed into a live graph, trained on or repaired."""
    if not text:
        raise argparse.ArgumentTypeError("'' is empty; give a path (. for the current directory)")
    return text


def input_path(text: str) -> Path:
    """``input_text`` as a Path."""
    return Path(input_text(text))


def output_dir(text: str) -> Path:
    """An ``--out`` directory: may exist (as a directory) or not yet; not an existing file."""
    return _checked(text, want_dir=True)


def bags_dir(text: str) -> Path:
    """An ``--out`` directory that receives episode bags: ``output_dir``, and neither a bag nor
    inside one (a ``metadata.yaml`` there or above): a reader takes a bag directory as one bag,
    so bags written into it were on disk and read by no tool (``--record`` given an existing bag)."""
    path = output_dir(text)
    for d in (path, *path.parents):
        if (d / "metadata.yaml").is_file():
            where = "is" if d == path else f"is inside {str(d)!r}, which is"
            raise argparse.ArgumentTypeError(f"{text!r} {where} a bag (it holds metadata.yaml): bags written there "
                                             "would be read by no tool; give the directory that holds the bags")
    return path


def output_file(text: str) -> Path:
    """An ``--out`` file: may exist (as a file, to be replaced) or not yet; not a directory."""
    return _checked(text, want_dir=False)


def file_stem(text: str) -> str:
    """A report's file name without suffix (``--name``), written inside ``--out``: one plain name,
    so that a report lands where ``--out`` says (no separator, no '..'), checked before the run."""
    if not text or text in (".", "..") or Path(text).name != text or "\\" in text:
        raise argparse.ArgumentTypeError(f"{text!r} must be a plain file name without a directory")
    return text


def refuse_directories(paths, hint: str = "give another --out") -> None:
    """ValueError naming the first of ``paths``, files a run is about to write, that is a
    directory: checked before the run, since found while writing it cost the whole run (an
    IsADirectoryError at the end, a temporary file left behind)."""
    for path in paths:
        if Path(path).is_dir():
            raise ValueError(f"{str(path)!r} is a directory where this run writes a file: move it away or {hint}")


def replace_atomically(path, write: Callable[[Path], object], suffix: str = ".tmp") -> Path:
    """``write(tmp)`` into a sibling of ``path`` (``suffix`` last, for writers that want theirs),
    then renamed onto ``path`` at once; the sibling is removed if writing fails or is interrupted.
    Why: a report, a checkpoint or a config written in place and interrupted (Ctrl-C, SIGTERM,
    a full disk) left a truncated file, and ``pinn_fusion_calibrate`` writes the shipped config
    the estimator reads at start by default."""
    path = Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}{suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_text_atomically(path, text: str) -> Path:
    """``text`` written to ``path`` through ``replace_atomically``: whole, or the old file untouched."""
    return replace_atomically(path, lambda tmp: tmp.write_text(text))


def save_figure_atomically(fig, path, dpi: int) -> Path:
    """A matplotlib figure saved to ``path`` through ``replace_atomically``, in the format its suffix
    names (none: PNG). Why: a figure written in place and interrupted left a truncated image, and
    the temporary sibling's own suffix would otherwise choose the format."""
    path = Path(path)
    fmt = path.suffix[1:].lower() or "png"
    return replace_atomically(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=fmt), suffix=f".tmp.{fmt}")


def written_since(path, since: float) -> bool:
    """Whether ``path`` was written at or after ``since`` (time.time()); False if it is gone (moved
    away meanwhile: by another run, a lost Ray cluster's worker), so a caller's error path says
    what is there and never fails on what is not."""
    try:
        return Path(path).stat().st_mtime >= since
    except OSError:
        return False
