"""``soil_bag_repair``: turn the journal a killed recorder left behind into a valid bag, or
copy the good chunks of a damaged finished bag into a new one.

``soil_bag_record`` writes each bag first as a journal ``<out>/<name>.partial/<name>.mcap``
(see ``journal.py``) and flushes it every ``--flush-period`` (0.25 s). After a SIGKILL,
OOM kill or crash, the journal holds every chunk flushed before the kill; this command
reads them with the truncation-tolerant MCAP stream reader, plus the episode metadata
record, and writes ``<out>/<name>/`` with the same conversion the recorder uses.

Worst-case loss: the messages received after the last flush, i.e. at most
``--flush-period`` of data, plus one tick when episode bags are trimmed to whole ticks
(the default, so ``bag_io.read_episode`` can read the result; ``--keep-partial-ticks``
keeps every recovered message). Not covered: a power cut (journals are not fsync'ed).
A journal chunk that fails its CRC (flipped bytes) is skipped, not the rest of the journal
(with the ticks its edges split, whose other messages lie in the chunks beside it);
each skipped chunk is printed (index, byte offset, log time range, messages per topic) and
recorded in the bag's custom_data ``insitu_soil.repair`` (``dropped_chunks``).

A finished bag whose chunks fail their CRC (``bag_io.read_episode`` refuses it, naming the
chunk) is repaired into a copy (``bag_salvage.py``): the chunks that pass are copied, the
others dropped and listed the same way, episode bags trimmed to ticks present on every
topic. The original is never touched; the copy goes to ``--out`` or, by default, beside it
as ``<bag>_repaired``.

    soil_bag_repair PATH [PATH ...] [--keep-partial-ticks] [--out NEW_BAG]

A finished bag whose metadata.yaml is missing or unreadable is copied the same way, its
metadata.yaml rebuilt from the record of it its .mcap carries.

PATH is a ``*.partial`` directory, the journal ``.mcap`` inside one, a finished bag
directory (or its .mcap), or a directory that is searched for ``*.partial`` directories. ``--out`` names
the repaired copy of a finished bag (one PATH only). Exit code 1 if some path had nothing
to recover (an undamaged bag, a bag without CRCs, an empty journal) or was skipped (a journal a
running recorder is still writing: it holds the journal's lock), 2 for bad arguments (a PATH
that does not exist among them: said, after the others are done).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from soil_msgs_py.cli_paths import input_path, output_dir

from .bag_io import PARTIAL_SUFFIX, find_episode_bags, is_bag
from .bag_salvage import salvage_bag
from .journal import REPAIR_INFO_KEY, BagResult, JournalInUse, NothingRecoverable, journal_to_bag


def finished_bag_dir(path: Path) -> bool:
    """A finished bag's directory (not a journal's): one with its metadata.yaml, or one holding a
    single .mcap and nothing else, its metadata.yaml gone (``bag_salvage.embedded_info`` rebuilds
    it). A directory with more in it (journals, other bags, loose files) is one to search."""
    if not path.is_dir() or path.name.endswith(PARTIAL_SUFFIX):
        return False
    if is_bag(path):
        return True
    entries = [p for p in path.iterdir() if not p.name.startswith(".")]
    return len(entries) == 1 and entries[0].is_file() and entries[0].suffix == ".mcap"


def _bag_of_file(path: Path) -> Path:
    """A finished bag's .mcap given as PATH stands for its directory (a journal's, or a loose file's
    in a directory that is no bag, stays itself)."""
    if path.is_file() and path.suffix == ".mcap" and finished_bag_dir(path.parent):
        return path.parent
    return path


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
        bags = find_episode_bags(path)
        lost = sorted(p for p in path.rglob("*") if finished_bag_dir(p) and not is_bag(p))
        raise NothingRecoverable(f"{path}: no *{PARTIAL_SUFFIX} journal directory inside" + (
            f"; of its {len(bags)} finished bag(s) give each damaged one as PATH (a reader names it) to copy its "
            "good chunks" if bags else "") + (
            f"; {len(lost)} bag director{'y' if len(lost) == 1 else 'ies'} without a metadata.yaml "
            f"({', '.join(str(p) for p in lost[:3])}{' …' if len(lost) > 3 else ''}): give each as PATH to rebuild it"
            if lost else ""))
    if not path.exists():
        raise NothingRecoverable(f"{path} does not exist")
    raise NothingRecoverable(f"{path} is neither a *{PARTIAL_SUFFIX} directory, its journal .mcap, nor a directory")


def repair(partial: Path, *, keep_partial_ticks: bool = False) -> BagResult:
    """Convert one journal directory; raises NothingRecoverable (journal kept) if empty."""
    return journal_to_bag(partial, trim_partial_ticks=not keep_partial_ticks, info_key=REPAIR_INFO_KEY,
                          info={"keep_partial_ticks": keep_partial_ticks})


def free_name(bag: Path) -> Path:
    """``<bag>_repaired``, or ``_repaired_2``... : the first name not taken beside ``bag``."""
    k = 1
    while (cand := bag.with_name(f"{bag.name}_repaired" + (f"_{k}" if k > 1 else ""))).exists() or \
            cand.with_name(cand.name + PARTIAL_SUFFIX).exists():
        k += 1
    return cand


def report(r: BagResult, state: str) -> None:
    print(f"repaired {r.summary()}; recovered {r.recovered} messages from the {state}, "
          f"last stamp {r.last_stamp_ns} ns")
    for line in r.dropped_chunks:
        print(f"  dropped {line}")
    if r.torn_chunk:
        print(f"  kept the whole records of {r.torn_chunk}")


def main(args: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="soil_bag_repair", description=__doc__.split("\n\n")[0])
    p.add_argument("paths", nargs="+", type=input_path, metavar="PATH",
                   help="*.partial directory, its journal .mcap, a finished bag, or a directory to search")
    p.add_argument("--keep-partial-ticks", action="store_true",
                   help="keep ticks that lack some topics (the readers then drop them as gaps, and say so)")
    p.add_argument("--out", type=output_dir, metavar="NEW_BAG",
                   help="where the repaired copy of a finished bag goes (default: <bag>_repaired beside it)")
    opts = p.parse_args(sys.argv[1:] if args is None else args)
    opts.paths = [_bag_of_file(path) for path in opts.paths]
    bags = [path for path in opts.paths if finished_bag_dir(path)]
    if opts.out is not None and (len(opts.paths) != 1 or not bags):
        p.error(f"--out {opts.out}: give exactly one finished bag PATH with it (got {len(opts.paths)} "
                f"path(s), {len(bags)} finished bag(s))")
    if opts.out is not None and (opts.out.exists() or opts.out.is_symlink()):
        p.error(f"--out {opts.out} exists; the repaired copy never replaces anything")
    if opts.out is not None and opts.out.resolve().is_relative_to(bags[0].resolve()):  # no search looks in a bag
        p.error(f"--out {opts.out} is inside the bag {bags[0]}, where no reader would find the copy; put it beside it")
    # a mistyped path is a bad argument (exit 2 once every other path is done), not a bag with
    # nothing to recover (exit 1)
    missing = sum(not path.exists() and not path.is_symlink() for path in opts.paths)
    failed = 0
    for path in opts.paths:
        if path in bags:
            try:
                r = salvage_bag(path, opts.out or free_name(path), keep_partial_ticks=opts.keep_partial_ticks)
            except (ValueError, OSError) as err:  # NothingRecoverable, BagReadError, --out taken
                print(f"soil_bag_repair: nothing repaired: {err}", file=sys.stderr)
                failed += 1
                continue
            report(r, f"bag {path}, its metadata.yaml rebuilt from the .mcap's own record ({r.metadata_from_mcap})"
                   if r.metadata_from_mcap else f"chunks of {path} that pass their CRC")
            continue
        try:
            partials = find_partials(path)
        except NothingRecoverable as err:
            print(f"soil_bag_repair: nothing recoverable: {err}", file=sys.stderr)
            failed += 1
            continue
        for partial in partials:
            try:
                r = repair(partial, keep_partial_ticks=opts.keep_partial_ticks)
            except JournalInUse as err:
                print(f"soil_bag_repair: skipped {partial}: {err}", file=sys.stderr)
                failed += 1
                continue
            except (NothingRecoverable, ValueError, OSError) as err:
                print(f"soil_bag_repair: nothing recoverable from {partial}: {err}", file=sys.stderr)
                failed += 1
                continue
            report(r, "complete journal" if r.journal_complete else f"truncated journal ({r.stop})")
    return 2 if missing else 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
