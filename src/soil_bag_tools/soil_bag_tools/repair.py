"""``soil_bag_repair``: turn the journal a killed recorder left behind into a valid bag.

``soil_bag_record`` writes each bag first as a journal ``<out>/<name>.partial/<name>.mcap``
(see ``journal.py``) and flushes it every ``--flush-period`` (0.25 s). After a SIGKILL,
OOM kill or crash, the journal holds every chunk flushed before the kill; this command
reads them with the truncation-tolerant MCAP stream reader, plus the episode metadata
record, and writes ``<out>/<name>/`` with the same conversion the recorder uses.

Worst-case loss: the messages received after the last flush, i.e. at most
``--flush-period`` of data, plus one tick when episode bags are trimmed to whole ticks
(the default, so ``bag_io.read_episode`` can read the result; ``--keep-partial-ticks``
keeps every recovered message). Not covered: a power cut (journals are not fsync'ed).

    soil_bag_repair PATH [PATH ...] [--keep-partial-ticks]

PATH is a ``*.partial`` directory, the journal ``.mcap`` inside one, or a directory that
is searched for ``*.partial`` directories. Exit code 1 if some path had nothing to recover.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .bag_io import PARTIAL_SUFFIX
from .journal import REPAIR_INFO_KEY, BagResult, NothingRecoverable, journal_to_bag


def find_partials(path: Path) -> list[Path]:
    """The journal directories ``path`` names or contains; ValueError if there are none."""
    path = Path(path)
    if path.is_file() and path.suffix == ".mcap" and path.parent.name.endswith(PARTIAL_SUFFIX):
        return [path.parent]
    if path.is_dir() and path.name.endswith(PARTIAL_SUFFIX):
        return [path]
    if path.is_dir():
        found = sorted(p for p in path.rglob(f"*{PARTIAL_SUFFIX}") if p.is_dir())
        if found:
            return found
        raise NothingRecoverable(f"{path}: no *{PARTIAL_SUFFIX} journal directory inside")
    if not path.exists():
        raise NothingRecoverable(f"{path} does not exist")
    raise NothingRecoverable(f"{path} is neither a *{PARTIAL_SUFFIX} directory, its journal .mcap, nor a directory")


def repair(partial: Path, *, keep_partial_ticks: bool = False) -> BagResult:
    """Convert one journal directory; raises NothingRecoverable (journal kept) if empty."""
    return journal_to_bag(partial, trim_partial_ticks=not keep_partial_ticks, info_key=REPAIR_INFO_KEY,
                          info={"keep_partial_ticks": keep_partial_ticks})


def main(args: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="soil_bag_repair", description=__doc__.split("\n\n")[0])
    p.add_argument("paths", nargs="+", type=Path, metavar="PATH",
                   help="*.partial directory, its journal .mcap, or a directory to search")
    p.add_argument("--keep-partial-ticks", action="store_true",
                   help="keep trailing ticks that lack some topics (the bag may then not read as an episode)")
    opts = p.parse_args(sys.argv[1:] if args is None else args)
    failed = 0
    for path in opts.paths:
        try:
            partials = find_partials(path)
        except NothingRecoverable as err:
            print(f"soil_bag_repair: nothing recoverable: {err}", file=sys.stderr)
            failed += 1
            continue
        for partial in partials:
            try:
                r = repair(partial, keep_partial_ticks=opts.keep_partial_ticks)
            except (NothingRecoverable, ValueError, OSError) as err:
                print(f"soil_bag_repair: nothing recoverable from {partial}: {err}", file=sys.stderr)
                failed += 1
                continue
            state = "complete journal" if r.journal_complete else f"truncated journal ({r.stop})"
            print(f"repaired {r.summary()}; recovered {r.recovered} messages from the {state}, "
                  f"last stamp {r.last_stamp_ns} ns")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
