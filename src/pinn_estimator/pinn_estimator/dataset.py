"""Training data from a directory of episode bags: arrays, 60-sample windows, split by episode.

The bags stay the source of truth (read with ``rosbags`` through ``soil_bag_tools.bag_io``);
the arrays are cached in an ``.npz`` keyed by a content fingerprint of the bags, so a second
run reads in a fraction of a second and a changed bag can never be served stale. A bag that
cannot be read or trained on (``BagReadError``: truncated, corrupt, NaN, too short) stops the
load naming it, or is skipped and reported when the user asks (``skip_bad_bags``); a dataset
with a skipped bag is never cached, so the cache always stands for every bag of its directory.

A window is the T = 60 samples o_[t-59 .. t] (paper §2.2.1); its target is the force measured
at t and its known parameters Θ_k are those at t, the newest sample, which is what the online
estimator has when it publishes an estimate stamped with sample t.
"""
from __future__ import annotations

import dataclasses
import hashlib
import re
import sys
import zipfile
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from soil_bag_tools.bag_io import BagReadError, passed_by_note, read_episode, reader_notes, scan_bags
from soil_msgs_py.cli_paths import replace_atomically
from soil_msgs_py.episode import MODEL_INPUTS, EpisodeMeta, first_implausible, stamp_gaps, world_modes
from soil_msgs_py.values import PLAUSIBLE_ABS_LIMIT
from soil_msgs_py.params import WINDOW_SAMPLES
from soil_physics.travel import distance_in_soil_of_known, time_in_soil_of_known
from soil_sim_node.ray_cluster import CLUSTER_LOST_AFTER_S

# Samples between window ends at most: 600, 10 s at 60 Hz, the length of this project's
# episodes. A larger stride leaves one window per episode, and a run on a handful of windows
# (pinn_train --stride 100000 trained on 24 of them, pinn_eval scored 12) is no run.
MAX_WINDOW_STRIDE = 10 * WINDOW_SAMPLES
CACHE_VERSION = 2  # 2: per-row stamp gaps (``Dataset.gap_before``) (it is in the fingerprint: checkpoints record it)
CACHE_DIR_NAME = ".insitu_cache"
SPLITS = ("train", "val", "test")
SKIP_BAD_BAGS_HELP = ("skip bags that cannot be read (truncated, corrupt, NaN, shorter than a window) and "
                      "list them; by default such a bag stops the run, named")


@dataclass
class Dataset:
    """All episodes of a bag directory, concatenated row-wise (one row per 60 Hz tick).

    ``offsets[e]:offsets[e+1]`` are the rows of episode ``e``; ``names[e]`` its bag name.
    """

    names: list[str]
    metas: list[EpisodeMeta]
    offsets: np.ndarray  # (E+1,) int64
    observations: np.ndarray  # (N, 9) float64, OBSERVATION_FIELDS
    forces: np.ndarray  # (N, 2) float64, FORCE_FIELDS [N]
    known: np.ndarray  # (N, 9) float64, KNOWN_PARAMS [SI]
    truth: np.ndarray  # (N, 13) float64, GROUND_TRUTH_PARAMS [SI]; never an input to the model
    fingerprint: str
    root: str
    skipped: list[dict] = field(default_factory=list)  # {"bag": path, "problem": why} per skipped bag
    notes: list[str] = field(default_factory=list)  # the bag readers' warnings (``bag_io.reader_notes``)
    # (N,) bool: the row's stamp is more than one tick after the previous row of its episode (a
    # bag repaired by dropping damaged chunks); None: no gaps
    gap_before: np.ndarray | None = None

    def __post_init__(self):
        if self.gap_before is None:
            self.gap_before = np.zeros(len(self.observations), bool)

    def __len__(self) -> int:
        return len(self.names)

    @classmethod
    def from_episodes(cls, episodes, root: str = "(in memory)") -> "Dataset":
        """Episodes simulated in this process (``soil_sim_node.rollout.run_episodes``) as a Dataset,
        no bags involved (the forecast evaluation's own held-out episodes)."""
        if not episodes:
            raise ValueError("no episodes to make a dataset of")
        names = [ep.meta.name for ep in episodes]
        offsets = np.concatenate([[0], np.cumsum([len(ep.stamps_ns) for ep in episodes])]).astype(np.int64)
        arrays = (np.concatenate([getattr(ep, k) for ep in episodes]) for k in ("observations", "forces", "known", "truth"))
        return cls(names, [ep.meta for ep in episodes], offsets, *arrays, fingerprint="", root=root,
                   gap_before=np.concatenate([stamp_gaps(ep.stamps_ns) for ep in episodes]))

    def episode_rows(self, e: int) -> slice:
        return slice(int(self.offsets[e]), int(self.offsets[e + 1]))

    def window_ends(self, episodes, stride: int = 1, window: int = WINDOW_SAMPLES) -> np.ndarray:
        """Global row index of the newest sample of every full window of the given episodes.

        Windows never cross an episode boundary; the first full window ends at row
        ``window - 1`` of its episode; then one every ``stride`` rows. A window that would
        span a gap in the stamps is left out, as the online estimator empties its window at a
        missing tick: its samples would not be one second of motion.
        """
        if stride < 1:
            raise ValueError(f"stride={stride} must be >= 1 sample")
        ends = [np.arange(self.offsets[e] + window - 1, self.offsets[e + 1], stride) for e in episodes]
        ends = np.concatenate(ends).astype(np.int64) if ends else np.zeros(0, np.int64)
        if self.gap_before.any() and len(ends):
            gaps = np.concatenate([[0], np.cumsum(self.gap_before)])  # gaps[i]: gaps before row i
            ends = ends[gaps[ends + 1] == gaps[ends - window + 2]]  # none after the window's first row
        return ends

    def episode_of_rows(self, rows: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.offsets, rows, side="right") - 1

    def distance_in_soil(self) -> np.ndarray:
        """(N,) blade travel in soil [m] at every row, restarting at each episode's first tick
        (``soil_physics.travel.distance_in_soil`` per episode, from Θ_k's v_x and d). Computed,
        not cached: it is a pure function of ``known``, so a cached dataset can never disagree
        with it."""
        return self._per_episode(distance_in_soil_of_known)

    def time_in_soil(self) -> np.ndarray:
        """(N,) time with the blade in the soil [s] at every row, restarting at each episode's
        first tick (``soil_physics.travel.time_in_soil`` per episode, from Θ_k's d); computed
        like ``distance_in_soil``."""
        return self._per_episode(time_in_soil_of_known)

    def _per_episode(self, of_known) -> np.ndarray:
        out = np.zeros(len(self.known))
        for e in range(len(self)):
            rows = self.episode_rows(e)
            out[rows] = of_known(self.known[rows])
        return out

    def index(self, names, *, fix: str = "evaluate on the directory the model was trained from") -> list[int]:
        """Episode indices of bag names; raises counting the names that are not here, naming the
        first, and saying ``fix``."""
        where = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in where]
        unreadable = {Path(s["bag"]).name: s["problem"] for s in self.skipped}
        if skipped := [n for n in missing if n in unreadable]:  # (here, but left out: "not in the dataset" misled)
            raise ValueError(
                f"{len(skipped)} episode(s) of the split were skipped as unreadable (--skip-bad-bags), e.g. "
                f"{skipped[0]!r}: {unreadable[skipped[0]]}; repair it (soil_bag_repair) and run again"
                + (f" ({len(missing) - len(skipped)} more are not in the dataset at {self.root}: {fix})"
                   if len(missing) > len(skipped) else "")
            )
        if missing:
            raise ValueError(
                f"{len(missing)} episode(s) of the split are not in the dataset at {self.root}, "
                f"e.g. {missing[0]!r}: {fix}"
            )
        return [where[n] for n in names]


# ---------------------------------------------------------------------------------- loading
def fingerprint_bags(bags: list[Path], root: Path) -> str:
    """sha256 over every bag's relative path and the bytes of each of its files."""
    h = hashlib.sha256(f"insitu-soil-dataset-v{CACHE_VERSION}".encode())
    for bag in bags:
        h.update(str(bag.relative_to(root) if bag != root else bag.name).encode())
        for f in sorted(p for p in bag.iterdir() if p.is_file()):
            h.update(f.name.encode())
            with f.open("rb") as fh:
                for chunk in iter(lambda: fh.read(1 << 20), b""):
                    h.update(chunk)
    return h.hexdigest()


def _read(bag: Path):
    """Worker: one bag's arrays, or its BagReadError *returned* (picklable), so a pool reading
    many bags keeps going and the parent decides whether to skip the bag or stop."""
    try:
        with reader_notes() as notes:
            ep = read_episode(bag)
        if len(ep.observations) < WINDOW_SAMPLES:
            raise BagReadError(bag, f"has {len(ep.observations)} ticks, fewer than one {WINDOW_SAMPLES}-sample window")
        for name, attr, fields in MODEL_INPUTS:
            _check_plausible(name, getattr(ep, attr), fields, bag)
    except BagReadError as err:
        return err
    return bag.name, ep.meta.to_json(), ep.observations, ep.forces, ep.known, ep.truth, stamp_gaps(ep.stamps_ns), notes


def _check_plausible(name: str, arr: np.ndarray, fields, bag: Path) -> None:
    if (first := first_implausible(arr, fields)) is not None:
        field, value, row, _ = first
        raise BagReadError(bag, f"{name} field {field!r} is {value} at tick {row}; a window with NaN/inf or a value "
                                f"beyond ±{PLAUSIBLE_ABS_LIMIT:g} (no sensor's in SI, a fault's) can be neither "
                                "trained on nor scored (re-record or drop the bag)")


def _warn(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def say_notes(notes: list[str], log=_warn) -> None:
    """The bag readers' warnings of a dataset (``bag_io.reader_notes``), each kind once with how
    many bags it concerns: said whether the bags were read or their cache was."""
    by_kind: dict[str, list[tuple[str, str]]] = defaultdict(list)
    for note in notes:
        bag, sep, text = note.partition(": ")
        bag, text = (bag, text) if sep else ("", note)
        by_kind[re.sub(r"\d+(\.\d+)?", "#", text)].append((bag, text))  # (its counts and stamps are the bag's)
    for said in by_kind.values():
        (bag, text), others = said[0], (f" (and {len(said) - 1} other bag(s) alike)" if len(said) > 1 else "")
        log(f"warning: {bag}: {text}{others}" if bag else f"warning: {text}{others}")


def add_skip_bad_bags_option(parser) -> None:
    """``--skip-bad-bags`` for every CLI that loads a bag directory (one wording everywhere)."""
    parser.add_argument("--skip-bad-bags", action="store_true", help=SKIP_BAD_BAGS_HELP)


def load_dataset(root, *, cache: bool = True, cache_dir=None, workers: int = 1, progress: bool = False,
                 skip_bad_bags: bool = False, log=_warn, ray_address: str | None = None,
                 ray_give_up_after_s: float = CLUSTER_LOST_AFTER_S) -> Dataset:
    """Read every episode bag under ``root`` (cached by content fingerprint).

    Raises ValueError naming the problem for an empty directory and BagReadError naming the
    first bad bag (truncated, corrupt, missing a topic, a NaN/inf or implausible input or force, shorter than
    a window). With ``skip_bad_bags`` the bad bags are left out instead, listed in
    ``Dataset.skipped`` and reported through ``log`` (default: stderr); the fingerprint is
    then that of the bags kept, and the result is not cached.

    ``ray_address``: read the bags as Ray tasks (``soil_sim_node.ray_cluster``: ``LOCAL`` for a
    local instance of ``workers`` CPUs, or a cluster's address, whose nodes must see ``root`` at
    the same path); the arrays are the same as the local reader's. ``ray_give_up_after_s``: how
    long its head may refuse connections (``run_tasks``).
    """
    root = Path(root)
    bags, strays = scan_bags(root)
    note = passed_by_note(strays, root)
    if not bags:
        raise ValueError(f"no episode bags under {root} (expected rosbag2 directories with metadata.yaml)"
                         + (f"; {note}" if note else ""))
    if note:
        log(f"{root}: {note}")
    fingerprint = fingerprint_bags(bags, root)
    cache_path = Path(cache_dir or root / CACHE_DIR_NAME) / f"dataset_{fingerprint[:24]}.npz"
    if cache and cache_path.is_file():
        cached = _from_npz(cache_path, fingerprint, root)
        if cached is not None:
            say_notes(cached.notes, log)
            if ray_address:  # (a wrong address would otherwise surface only once the bags change)
                log(f"note: the dataset's cache answered for {root}; no bag was read, on Ray or otherwise "
                    f"(--ray {ray_address} not contacted; --no-cache reads the bags there)")
            return cached
    rows = (_read_on_ray(bags, workers, progress, ray_address, ray_give_up_after_s) if ray_address
            else _read_all(bags, workers, progress))
    bad = [r for r in rows if isinstance(r, BagReadError)]
    if bad and not skip_bad_bags:
        first = bad[0]
        raise BagReadError(first.bag, f"{first.problem} ({len(bad)} of {len(bags)} bags under {root} cannot be "
                                      f"read; --skip-bad-bags leaves them out)")
    if bad:
        log(f"skipped {len(bad)} of {len(bags)} bags under {root} that cannot be read:\n"
            + "\n".join(f"  {err}" for err in bad))
        if len(bad) == len(bags):
            raise ValueError(f"every bag under {root} is unreadable; nothing left to load")
        bags = [b for b, r in zip(bags, rows) if not isinstance(r, BagReadError)]
        fingerprint = fingerprint_bags(bags, root)
    names, metas, parts, notes = [], [], defaultdict(list), []
    for name, meta_json, obs, forces, known, truth, gaps, said in (r for r in rows if not isinstance(r, BagReadError)):
        names.append(name)
        notes += said
        metas.append(EpisodeMeta.from_json(meta_json))
        for key, arr in (("observations", obs), ("forces", forces), ("known", known), ("truth", truth),
                         ("gap_before", gaps)):
            parts[key].append(arr)
    if len(set(names)) != len(names):
        dup = sorted(n for n in set(names) if names.count(n) > 1)[0]
        where = ", ".join(str(b) for b, n in zip(bags, names) if n == dup)
        raise ValueError(f"two bags under {root} are named {dup!r} ({where}); splits are by bag name, so names must be "
                         "unique")
    offsets = np.concatenate([[0], np.cumsum([len(a) for a in parts["observations"]])]).astype(np.int64)
    ds = Dataset(
        names, metas, offsets, *(np.concatenate(parts[k]) for k in ("observations", "forces", "known", "truth")),
        fingerprint=fingerprint, root=str(root), skipped=[{"bag": e.bag, "problem": e.problem} for e in bad],
        gap_before=np.concatenate(parts["gap_before"]), notes=notes,
    )
    say_notes(notes, log)
    if cache and not bad:
        _to_npz(ds, cache_path)
    return ds


def _read_all(bags, workers, progress):
    def shown(it):
        if not progress:
            return it
        from tqdm import tqdm

        return tqdm(it, total=len(bags), desc="reading bags", unit="bag")

    if workers > 1 and len(bags) > 1:
        from soil_msgs_py.process_pool import map_in_processes

        return list(shown(map_in_processes(_read, bags, min(workers, len(bags)), what="reading bags", chunksize=4)))
    return [_read(b) for b in shown(bags)]


RAY_BAGS_PER_TASK = 16  # bags one Ray task reads: amortises the task overhead, keeps tasks short


def _read_bags(bags: list[Path]) -> list:
    """Ray task: ``_read`` of each bag."""
    return [_read(b) for b in bags]


def _read_on_ray(bags, workers, progress, ray_address, give_up_after_s: float) -> list:
    """``_read`` of every bag, in bag order, as Ray tasks of ``RAY_BAGS_PER_TASK`` bags."""
    from soil_sim_node.ray_cluster import ray_session, run_tasks

    # a cluster's workers start where `ray start` ran: they read the bags by their absolute paths (on
    # storage every machine mounts there); a bag that cannot be read is said by the path as given
    given = [Path(b).absolute() for b in bags]
    groups = [given[i : i + RAY_BAGS_PER_TASK] for i in range(0, len(given), RAY_BAGS_PER_TASK)]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(bags), desc="reading bags (Ray)", unit="bag")
    with ray_session(ray_address, num_cpus=max(1, workers)):
        done = run_tasks(_read_bags, groups, on_done=lambda r: bar and bar.update(0 if isinstance(r, Exception) else len(r)),
                         lost_after_s=give_up_after_s)
    if bar is not None:
        bar.close()
    for i, (group, result) in enumerate(zip(groups, done)):
        if isinstance(result, Exception):
            raise RuntimeError(f"the Ray task reading {len(group)} bags (from {bags[i * RAY_BAGS_PER_TASK]} on) failed: "
                               f"{type(result).__name__}: {result}")
    rows = [row for result in done for row in result]
    return [BagReadError(bag, r.problem) if isinstance(r, BagReadError) else r for bag, r in zip(bags, rows)]


def _to_npz(ds: Dataset, path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        replace_atomically(path, lambda tmp: np.savez(  # (.npz last: savez adds it to a name without it)
            tmp, version=CACHE_VERSION, fingerprint=ds.fingerprint, names=np.array(ds.names),
            metas=np.array([m.to_json() for m in ds.metas]), offsets=ds.offsets,
            observations=ds.observations, forces=ds.forces, known=ds.known, truth=ds.truth, gap_before=ds.gap_before,
            notes=np.array(ds.notes, dtype=str),
        ), suffix=".tmp.npz")
    except OSError:
        pass  # a read-only dataset directory just means no cache


def _from_npz(path: Path, fingerprint: str, root: Path) -> Dataset | None:
    """The cached dataset, or None (read the bags again) if the cache file is damaged or stale, or
    holds a value the readers now refuse (a cache written before they refused values beyond
    ±``PLAUSIBLE_ABS_LIMIT``: read again, the bag is named)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["version"]) != CACHE_VERSION or str(z["fingerprint"]) != fingerprint or "notes" not in z.files:
                return None  # (a cache from before the readers' warnings were kept: read the bags again)
            if any(first_implausible(z[attr], fields) is not None for _, attr, fields in MODEL_INPUTS):
                return None
            return Dataset(
                [str(n) for n in z["names"]], [EpisodeMeta.from_json(str(m)) for m in z["metas"]], z["offsets"],
                z["observations"], z["forces"], z["known"], z["truth"], fingerprint=fingerprint, root=str(root),
                gap_before=z["gap_before"], notes=[str(n) for n in z["notes"]],
            )
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None


# ---------------------------------------------------------------------------------- split
def identical_episodes(ds: Dataset) -> list[list[str]]:
    """Groups (sorted, of two or more) of one episode recorded more than once: two recorders on one
    graph, a replay recorded again (``soil_bag_play --loop``) write it under other names, and in
    the noise-free fee world the seeds of one grid point make the same episode. Judged by the
    metadata (the bag name and the seed aside) and the samples (forces, Θ_k, observations): a
    test episode whose every sample a training episode holds is no held-out episode, whatever its
    seed (an outside reviewer's: 50 of the fee model's 72 test episodes had such a twin in
    training, and scored 1.9 % where the 22 without one scored 3.4 %). A recording cut short (a
    replay stopped part-way, recorded under another name) holds the first samples of its episode:
    one whose samples all begin another of the same metadata is that episode too (an outside
    tester's: such a prefix went to test with its whole episode in training), if it holds at least a
    window of them: the default world's seeds share their first sample. Compared within groups of
    one metadata and first window, so the work grows with the copies, not the episodes squared."""
    by_meta: dict[tuple, list[int]] = defaultdict(list)
    for e in range(len(ds.names)):
        rows = ds.episode_rows(e)
        first = tuple(np.ascontiguousarray(a[rows][:WINDOW_SAMPLES]).tobytes()
                      for a in (ds.forces, ds.known, ds.observations))
        by_meta[(repr(dataclasses.astuple(dataclasses.replace(ds.metas[e], seed=0))), first)].append(e)
    same = list(range(len(ds.names)))  # union-find over the episodes: each one's representative

    def find(e: int) -> int:
        while same[e] != e:
            same[e] = same[same[e]]
            e = same[e]
        return e

    for members in by_meta.values():
        samples = {e: [a[ds.episode_rows(e)] for a in (ds.forces, ds.known, ds.observations)] for e in members}
        for i, a in enumerate(members):
            for b in members[i + 1:]:
                lengths = len(samples[a][0]), len(samples[b][0])
                n = min(lengths)  # (of one length, a copy however short)
                if ((n >= WINDOW_SAMPLES or lengths[0] == lengths[1]) and find(a) != find(b)
                        and all(np.array_equal(x[:n], y[:n]) for x, y in zip(samples[a], samples[b]))):
                    same[find(a)] = find(b)
    groups: dict[int, list[str]] = defaultdict(list)
    for e, name in enumerate(ds.names):
        groups[find(e)].append(name)
    return sorted(sorted(names) for names in groups.values() if len(names) > 1)


def split_episodes(ds: Dataset, *, seed: int, val_fraction: float = 0.15, test_fraction: float = 0.15) -> dict[str, list[str]]:
    """Split bag names into train/val/test **by episode**, stratified by (world, soil, I_d).

    Every window of an episode lands in one split, and so do episodes identical to it
    (``identical_episodes``), so the test score measures episodes the model has never seen.
    Stratifying (over distinct episodes) keeps every soil and density in every split when the
    grid has at least three episodes per cell. The cells of one or two episodes are split
    together, as one more cell: alone each would keep its episodes for training, and beside
    larger cells those soils never reached validation or test, without a word (an outside
    tester's: four Sand episodes beside Clay cells of four). A split asked for and still empty
    gets ``round(fraction · episodes)`` (at least one) drawn from the training episodes, across
    cells, validation first (training stops early on it), while one is left to train on.
    """
    for name, f in (("val_fraction", val_fraction), ("test_fraction", test_fraction)):
        if not 0.0 <= f < 1.0:
            raise ValueError(f"{name}={f} must be in [0, 1)")
    if val_fraction + test_fraction >= 1.0:
        raise ValueError(f"val_fraction + test_fraction = {val_fraction + test_fraction} leaves no training episodes")
    # identical episodes (copies under other names, a noise-free world's seeds) are split as one:
    # the first stands for them and the others go where it went. A copy of a training episode in the
    # test split is no held-out episode; and moved after the split, a small grid's copies could all
    # follow their first into validation or test and leave nothing to train on
    copies = identical_episodes(ds)
    copy_names = {name for names in copies for name in names[1:]}
    distinct = len(ds.names) - len(copy_names)
    groups: dict[tuple, list[str]] = defaultdict(list)
    for name, meta in zip(ds.names, ds.metas):
        if name not in copy_names:
            groups[(meta.world_mode, meta.soil, float(meta.relative_density_pct))].append(name)
    rng = np.random.default_rng(seed)
    out = {s: [] for s in SPLITS}
    small = sorted(name for key in groups if len(groups[key]) < 3 for name in groups[key])
    cells = [sorted(groups[key]) for key in sorted(groups) if len(groups[key]) >= 3] + ([small] if small else [])
    for members in cells:
        rng.shuffle(members)
        n = len(members)
        n_test = int(round(test_fraction * n))
        n_val = int(round(val_fraction * n))
        if n >= 3:
            n_test, n_val = max(n_test, 1 if test_fraction > 0 else 0), max(n_val, 1 if val_fraction > 0 else 0)
        n_test = min(n_test, max(n - 1, 0))
        n_val = min(n_val, max(n - 1 - n_test, 0))
        out["test"] += members[:n_test]
        out["val"] += members[n_test : n_test + n_val]
        out["train"] += members[n_test + n_val :]
    for split, fraction in (("val", val_fraction), ("test", test_fraction)):  # validation first: training needs it
        if fraction > 0 and not out[split] and len(out["train"]) > 1:
            n = min(max(1, int(round(fraction * distinct))), len(out["train"]) - 1)
            moved = sorted(rng.choice(sorted(out["train"]), size=n, replace=False).tolist())
            out[split] = moved
            out["train"] = [name for name in out["train"] if name not in set(moved)]
    where = {name: split for split in SPLITS for name in out[split]}
    for names in copies:
        out[where[names[0]]] += names[1:]
    for s in SPLITS:
        out[s].sort()
    if not out["train"]:
        raise ValueError(f"dataset at {ds.root} has too few episodes ({len(ds)}"
                         + (f", {distinct} distinct: the others are copies" if copies else "") + ") for a train split")
    return out


def describe(ds: Dataset) -> dict:
    """Small JSON-able summary stored in checkpoints and reports."""
    modes = world_modes(ds.metas)
    soils = sorted({m.soil for m in ds.metas})
    return {
        "root": ds.root,
        "fingerprint": ds.fingerprint,
        "episodes": len(ds),
        "ticks": int(ds.offsets[-1]),
        "world_modes": modes,
        "soils": soils,
        "skipped_bags": [s["bag"] for s in ds.skipped],
    }
