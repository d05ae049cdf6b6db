"""Episodes as rosbag2 (version 9, MCAP, CDR, Jazzy types) bags, without a ROS install.

Bags are the dataset format: ``ros2 bag info/play`` can open them, and the trainer reads
them back bit-identically. Writes are atomic (staged in ``<bag>.partial``, renamed into
place after a clean close) so a crashed batch never leaves a bag that looks complete.
The episode metadata travels in metadata.yaml ``custom_data`` (and the MCAP metadata
record written alongside it). Every bag is written by ``bag_writer.BagWriter``: MCAP chunk,
data-section and summary CRCs, each topic's offered QoS and type hash. Reading checks those
CRCs first (``integrity.py``), so a damaged chunk is named (index, byte offset, log time
range, stored and computed CRC) instead of being decoded; bags from before CRCs were
written still read, with a one-line warning. Whatever else a damaged bag makes the reader
trip over surfaces as one :class:`BagReadError` naming the bag.
"""
from __future__ import annotations

import logging
import os
import shutil
import struct
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import apsw
import numpy as np
import yaml
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError
from rosbags.serde import SerdeError

try:  # the zstd rosbags decompresses with (a bag recorded with rosbag2's --compression-format zstd)
    from compression import zstd
except ImportError:  # (Python before 3.14)
    from backports import zstd

from soil_msgs_py import messages as M
from soil_msgs_py.episode import Episode, EpisodeMeta, first_implausible
from soil_msgs_py.params import KNOWN_PARAMS
from soil_msgs_py.values import short_repr
from soil_msgs_py.stream_checks import cutting_ticks, rate_problem, sign_problem
from soil_msgs_py.topics import CLOCK, EPISODE_TOPICS, GROUND_TRUTH
from .bag_writer import BagWriter, offered_qos
from .integrity import scan_file

META_KEY = "insitu_soil.episode"
PARTIAL_SUFFIX = ".partial"
log = logging.getLogger(__name__)

# What reading a damaged bag raises where no CRC caught it (bags without CRCs, damage outside
# the chunks): whatever rosbags' MCAP reader, its sqlite3 reader (apsw) and zstd decompression
# (rosbag2's .db3 and compressed bags: their errors had escaped every tool as a traceback, and
# --skip-bad-bags did not skip the bag), struct, the CDR decoder or our checks trip over; and a
# MemoryError, where a corrupt record length asks for more memory than exists.
DAMAGE_ERRORS = (AnyReaderError, ReaderError, SerdeError, struct.error, OverflowError, ValueError,
                 IndexError, KeyError, EOFError, OSError, zstd.ZstdError, apsw.Error, MemoryError)


class BagReadError(ValueError):
    """A bag that cannot be read as an episode: unfinished, truncated, corrupt or incomplete.

    One type for every cause, so offline tools name the bag and exit 2 (it is a ValueError,
    which they already treat as bad input) and a dataset loader can skip it by choice.
    Picklable with its fields: worker processes raise or return it to their parent.
    """

    def __init__(self, bag: str | os.PathLike, problem: str):
        self.bag, self.problem = str(bag), str(problem)
        super().__init__(f"bag {self.bag}: {self.problem}")

    def __reduce__(self):
        return type(self), (self.bag, self.problem)


class MetadataUnreadable(BagReadError):
    """A bag whose metadata.yaml no reader takes (missing, unparsable, or lacking a key rosbag2
    needs): ``reason`` says what is wrong; the message adds the command that rebuilds it, since
    rosbags' own words ("A metadata key is missing KeyError('version')") named neither."""

    def __init__(self, bag: str | os.PathLike, reason: str, hint: str | None = None):
        self.reason = str(reason)
        self.hint = self._hint(Path(bag)) if hint is None else hint  # (given again when unpickled: no second scan)
        super().__init__(bag, self.reason + self.hint)

    @staticmethod
    def _hint(bag: Path) -> str:
        """What rebuilds the metadata.yaml: the repair, from a bag's one .mcap (not a .db3's, nor from
        several files) that carries rosbag2's record of it; for a bag rosbag2 itself was stopped in,
        which has none (it had been sent to the repair, which then found nothing to rebuild it from:
        an outside tester's), rosbag2's reindex, after which the episode metadata is to be added again."""
        from .bag_salvage import embedded_metadata  # (it reads bags through this module)

        mcaps = [p for p in bag.glob("*.mcap") if p.is_file()]
        if len(mcaps) == 1 and embedded_metadata(mcaps[0]) is not None:
            return f"; `soil_bag_repair {bag}` rebuilds it from the record of it the .mcap carries"
        if mcaps or any(bag.glob("*.db3")):
            return ("; its storage carries no record of it to rebuild it from (a bag `ros2 bag record` was stopped "
                    f"before it wrote it): `ros2 bag reindex {bag}`, on a ROS install, rebuilds it from the messages, "
                    "without the episode metadata (add it again, README \"A machine's bags\")")
        return ""

    def __reduce__(self):
        return type(self), (self.bag, self.reason, self.hint)


@contextmanager
def reading(bag: str | os.PathLike) -> Iterator[None]:
    """Check ``bag``'s CRCs (:func:`check_integrity`), then turn any error of reading it into
    a BagReadError that names it."""
    try:
        check_integrity(Path(bag))
        yield
    except BagReadError:
        raise
    except DAMAGE_ERRORS as err:
        # our own ValueErrors are worded for the user; rosbags' need their type to make sense
        problem = (str(err) if type(err) is ValueError else
                   "unreadable (MemoryError: a corrupt length in it asks for more memory than exists, or it is too large "
                   "for this machine's memory)"
                   if isinstance(err, MemoryError) else f"corrupt or truncated ({type(err).__name__}: {err})")
        raise BagReadError(bag, problem) from err


def _check_arrays(ep: Episode, skip: tuple[str, ...] = ()) -> None:
    """Refuse what cannot round-trip or no reader takes: non-finite or implausible values (of the
    arrays not in ``skip``; ``episode.first_implausible``), bad or unordered stamps."""
    for name, fields in M.ARRAY_FIELDS.items():
        if name in skip:
            continue
        if (first := first_implausible(getattr(ep, name), fields)) is not None:
            field, value, row, _ = first
            raise ValueError(f"Episode.{name} column {field!r} is {value} at row {row} (first value non-finite or "
                             f"beyond ±{M.PLAUSIBLE_ABS_LIMIT:g}); bags must be finite and plausible")
    s = ep.stamps_ns
    if len(s) == 0:
        raise ValueError("episode has no ticks")
    if not np.issubdtype(s.dtype, np.integer):
        raise ValueError(f"Episode.stamps_ns must be integer ns, got dtype {s.dtype}")
    if s[0] < 0 or s[-1] // M.NS_PER_S > M.MAX_STAMP_SEC:
        raise ValueError(f"Episode.stamps_ns out of range [0, 2^31 s): {s[0]}..{s[-1]}")
    if len(s) > 1 and (back := np.flatnonzero(np.diff(s) <= 0)).size:
        i = int(back[0]) + 1
        raise ValueError(f"Episode.stamps_ns not strictly increasing at row {i}: {s[i - 1]} -> {s[i]}")


def journal_path(partial: Path) -> Path:
    """``<name>.partial/<name>.mcap``: where ``soil_bag_record`` journals the bag ``<name>``."""
    return partial / (partial.name[: -len(PARTIAL_SUFFIX)] + ".mcap")


def is_bag(path: Path) -> bool:
    """A finished rosbag2 directory (the writer renames metadata.yaml in last)."""
    return path.is_dir() and (path / "metadata.yaml").is_file()


def write_episode(bag_dir: str | os.PathLike, episode: Episode, *, overwrite: bool = False,
                  ground_truth: bool = True) -> Path:
    """Write ``episode`` as the bag directory ``bag_dir``; returns its path. ``ground_truth``
    False leaves out ``/soil/ground_truth`` (and ``episode.truth`` unchecked): the bag a real
    machine records, which knows no soil parameters, and whose world may be no simulator's
    (``world_mode`` "unknown", as the reader takes it: a user's converter of a machine's log had
    it refused)."""
    bag_dir = Path(bag_dir)
    episode.meta.validate(machine_world=not ground_truth)
    try:
        _check_arrays(episode, skip=() if ground_truth else ("truth",))
    except ValueError as err:  # (which bag: a batch of them was refused without its name)
        raise ValueError(f"bag {bag_dir} not written: {err}") from None
    if bag_dir.name.endswith(PARTIAL_SUFFIX):
        raise ValueError(f"bag name {bag_dir.name!r} must not end in {PARTIAL_SUFFIX}")
    if bag_dir.exists() or bag_dir.is_symlink():
        if is_bag(bag_dir):
            if not overwrite:
                raise FileExistsError(f"bag {bag_dir} exists; not replaced (soil_sim_batch --overwrite or "
                                      f"write_episode(overwrite=True) replaces it)")
        elif not bag_dir.is_dir() or any(bag_dir.iterdir()):
            raise FileExistsError(f"{bag_dir} exists and is not a rosbag2 bag; not touching it")

    staging = bag_dir.with_name(bag_dir.name + PARTIAL_SUFFIX)
    if journal_path(staging).exists():  # a killed recorder's messages, which soil_bag_repair recovers
        raise FileExistsError(f"{staging} holds a recorder's journal of a bag of this name; not touching it "
                              f"(soil_bag_repair {staging} recovers it, or move it away)")
    shutil.rmtree(staging, ignore_errors=True)  # left by a killed writer of this function: never valid
    staging.mkdir(parents=True)
    tmp_bag = staging / bag_dir.name  # mcap file is named after its directory
    try:
        with BagWriter(tmp_bag) as writer:
            writer.set_custom_data(META_KEY, episode.meta.to_json())
            conns = {
                t.name: writer.add_connection(t.name, t.msgtype, typestore=M.TYPESTORE,
                                              offered_qos_profiles=offered_qos(t.name))
                for t in EPISODE_TOPICS if ground_truth or t.name != GROUND_TRUTH.name
            }
            for topic, stamp, raw in M.serialize_episode(episode, M.TYPESTORE, topics=tuple(conns)):
                writer.write(conns[topic], stamp, raw)
        if not is_bag(tmp_bag):
            raise RuntimeError(f"rosbags wrote no metadata.yaml in {tmp_bag}")
        if bag_dir.exists():  # an old bag (overwrite) or an empty dir: park it in staging
            os.replace(bag_dir, staging / "replaced")
        os.replace(tmp_bag, bag_dir)
    except BaseException:
        if not bag_dir.exists() and (staging / "replaced").exists():
            os.replace(staging / "replaced", bag_dir)  # put the old bag back
        shutil.rmtree(staging, ignore_errors=True)
        raise
    shutil.rmtree(staging, ignore_errors=True)
    return bag_dir


_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


# What rosbag2 metadata must hold for rosbags' reader (0.11) to open a bag: the top-level keys (and
# the one key of the two mappings) and each topic entry's. This project's writer puts ``version``
# last (rosbag2's puts it first and ``relative_file_paths`` near the end), so a metadata.yaml cut
# short loses one of them, and still parses.
REQUIRED_METADATA = {"version": int, "relative_file_paths": list, "storage_identifier": str,
                     "topics_with_message_count": list, "duration": "nanoseconds",
                     "starting_time": "nanoseconds_since_epoch", "message_count": int}
REQUIRED_TOPIC_METADATA = ("name", "type", "serialization_format")


def metadata_problem(info: dict) -> str:
    """What ``rosbag2_bagfile_information`` lacks that a reader needs ("" if nothing): the one test of
    a metadata.yaml (and of the .mcap's record of it) beyond parsing."""
    lacking = []
    for key, kind in REQUIRED_METADATA.items():
        value = info.get(key)
        if isinstance(kind, str):
            if not (isinstance(value, dict) and isinstance(value.get(kind), int)):
                lacking.append(f"{key}.{kind}")
        elif not isinstance(value, kind) or isinstance(value, bool):
            lacking.append(key)
    lacking = [repr(k) for k in lacking]
    for k, entry in enumerate(info.get("topics_with_message_count") or []):
        topic = entry.get("topic_metadata") if isinstance(entry, dict) else None
        if not (isinstance(topic, dict) and all(isinstance(topic.get(n), str) for n in REQUIRED_TOPIC_METADATA)
                and isinstance(entry.get("message_count"), int)):
            lacking.append(f"a whole topics_with_message_count entry (its entry {k}: topic_metadata's "
                           f"{', '.join(REQUIRED_TOPIC_METADATA)} and message_count)")
            break
    if not lacking:
        return ""
    return (f"lacks {' and '.join(lacking)}, which rosbag2 requires (cut short or edited: it parses as YAML, but no "
            "reader takes it)")


def bag_info(bag: Path) -> dict:
    """metadata.yaml's ``rosbag2_bagfile_information``; MetadataUnreadable if it is missing, does not
    parse, or lacks what a reader needs (``metadata_problem``): the one place that calls a
    metadata.yaml garbled, for the readers and for ``soil_bag_repair``, which rebuilds such a one."""
    try:
        data = yaml.load((bag / "metadata.yaml").read_text(), Loader=_YAML_LOADER)
    except (OSError, ValueError, yaml.YAMLError) as err:
        # one line (a YAML error's repr dumped its parser's Mark objects)
        raise MetadataUnreadable(bag, f"unreadable metadata.yaml: {type(err).__name__}: "
                                      f"{' '.join(str(err).split())}") from None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict):  # (a bare string or list read as "string indices must be integers")
        raise MetadataUnreadable(bag, "unreadable metadata.yaml: not a rosbag2 metadata file (no mapping "
                                      f"'rosbag2_bagfile_information'; found {short_repr(data)})")
    if problem := metadata_problem(info):
        raise MetadataUnreadable(bag, f"unreadable metadata.yaml: it {problem}")
    return dict(info)


def bag_custom_data(bag: Path) -> dict[str, str]:
    """metadata.yaml ``custom_data`` (rosbags' reader has no public getter); {} if none."""
    info = bag_info(bag)
    try:
        return dict(info.get("custom_data") or {})
    except (ValueError, TypeError) as err:
        raise BagReadError(bag, f"unreadable metadata.yaml custom_data: {err!r}") from None


_warned_unchecked: set[str] = set()


def check_integrity(bag: Path) -> None:
    """Every chunk CRC (and the data-section and summary CRCs) of ``bag``'s MCAP files.

    BagReadError naming the first bad chunk (index, byte offset, log time range, what it held,
    stored vs computed CRC), a truncated file, or damage outside the chunks. A bag written
    before CRCs were (all 0: "not computed") passes with a one-line warning, once per process."""
    if not is_bag(bag):
        return  # callers say what is wrong with it
    files = bag_info(bag).get("relative_file_paths") or []
    for name in files:
        mcap = bag / str(name)
        if mcap.suffix != ".mcap":
            # a storage this project does not write (rosbag2's sqlite3 .db3, a whole file compressed
            # .mcap.zstd): rosbags reports what it cannot read, but a flipped byte it decodes is
            # read as data (an outside tester's: a position 0.09 m off, without a word)
            if str(bag) not in _warned_unchecked:
                _warned_unchecked.add(str(bag))
                kind = ("compressed as a whole (zstd)" if str(name).endswith(".zstd") else
                        "a sqlite3 file" if str(name).endswith(".db3") else f"a file of suffix {Path(str(name)).suffix!r}")
                log.warning("bag %s: %s is %s, which carries no CRCs this project checks; damage inside it cannot be "
                            "detected", bag, name, kind)
            continue
        if not mcap.is_file():
            raise BagReadError(bag, f"metadata.yaml lists {name}, which does not exist")
        scan = scan_file(mcap)
        if bad := scan.bad:
            others = f" (also chunk(s) {', '.join(str(c.index) for c in bad[1:])})" if len(bad) > 1 else ""
            raise BagReadError(bag, f"{name}: {bad[0].describe(scan.topics)}{others}; {len(bad)} of "
                                    f"{len(scan.chunks)} chunks are damaged, `soil_bag_repair {bag} "
                                    f"--out NEW_BAG` copies the others")
        # what soil_bag_repair can copy: the chunks that pass their CRC and a torn last one's whole records
        repair = (f"; `soil_bag_repair {bag} --out NEW_BAG` copies what it holds whole"
                  if (scan.chunks or scan.torn) and scan.has_crcs else "")
        if scan.stop:
            raise BagReadError(bag, f"{name} is truncated or unreadable ({scan.stop}){repair}")
        if scan.data_problem:
            raise BagReadError(bag, f"{name}: {scan.data_problem} (every chunk passes its CRC: "
                                    f"the damage is outside the chunks){repair}")
        if not scan.has_crcs and scan.chunks and str(bag) not in _warned_unchecked:
            _warned_unchecked.add(str(bag))
            log.warning("bag %s: written without chunk CRCs (by another tool, or by this project before it computed "
                        "them); "
                        "damage inside a chunk cannot be detected", bag)


@contextmanager
def reader_notes() -> Iterator[list[str]]:
    """The readers' warnings while inside (what a bag holds that its user must know: a force of
    the other sign, ticks dropped, no chunk CRCs), collected as lines instead of logged, for a
    caller that keeps them with what it read: a dataset cache had read them once and then
    answered without them (an outside tester's: a flipped sensor trained on in silence)."""
    notes: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            notes.append(record.getMessage())

    handler, propagate = Collect(logging.WARNING), log.propagate
    log.addHandler(handler)
    log.propagate = False
    try:
        yield notes
    finally:
        log.removeHandler(handler)
        log.propagate = propagate


def read_meta(path: Path) -> EpisodeMeta:
    """Episode metadata from metadata.yaml custom_data (BagReadError, a ValueError, naming what is wrong)."""
    custom = bag_custom_data(path)
    if META_KEY not in custom:
        raise BagReadError(path, f"has no episode metadata (custom_data key {META_KEY!r})")
    try:
        meta = EpisodeMeta.from_json(custom[META_KEY])
        meta.validate(machine_world=True)  # a density of 150 % or "eighty", a world "moon": named, never read on
        return meta
    except (TypeError, ValueError) as err:
        raise BagReadError(path, f"bad episode metadata {META_KEY!r}: {err}") from None


def read_episode(bag_dir: str | os.PathLike) -> Episode:
    """Read a bag written by ``write_episode`` back into an Episode (bit-identical arrays).

    ``/soil/ground_truth`` may be missing, as from a real machine, which knows no soil
    parameters: the Episode's ``truth`` is then NaN (``has_ground_truth`` False), and what scores
    against it says so; ``/clock`` may be missing too (a machine has no simulated clock: the
    ticks are the other topics' stamps); every other episode topic must be there. A tick some
    topic lacks is dropped, a gap as the live estimator makes of it, and said (``complete_ticks``);
    ticks that do not come at 60 Hz are refused, a force of the other sign is said
    (``soil_msgs_py.stream_checks``).

    FileNotFoundError if ``bag_dir`` does not exist; BagReadError for anything wrong with the bag."""
    path = Path(bag_dir)
    if not path.exists():
        raise FileNotFoundError(f"bag {path} does not exist")
    if path.name.endswith(PARTIAL_SUFFIX):
        raise BagReadError(path, f"is an unfinished bag (a write was interrupted; a killed recorder's journal: "
                                 f"soil_bag_repair {path} turns it into a bag)")
    if not is_bag(path):
        raise BagReadError(path, "is not a rosbag2 directory (no metadata.yaml)")
    meta = read_meta(path)
    with reading(path):
        with AnyReader([path], default_typestore=M.TYPESTORE) as reader:
            ns = topics_namespace(path, {c.topic for c in reader.connections})
            conns, stores = [], {}
            for t in EPISODE_TOPICS:
                mine = [c for c in reader.connections if c.topic == ns + t.name]
                if not mine and t.name in (GROUND_TRUTH.name, CLOCK.name):
                    continue  # a machine's bag: truth NaN, the ticks the others' stamps (below)
                if not mine:
                    raise BagReadError(path, f"has no topic {t.name} ({t.msgtype})")
                if wrong := {c.msgtype for c in mine} - {t.msgtype}:
                    raise BagReadError(path, f"topic {t.name} has type {wrong}, expected {t.msgtype}")
                conns += mine
                # Jazzy typestore if the embedded definition is Jazzy's (compiled once per process).
                same = all(c.digest == M.TYPESTORE.hash_rihs01(t.msgtype) for c in mine)
                stores[t.name] = M.TYPESTORE if same else reader.typestore
            raws: dict[str, list[bytes]] = defaultdict(list)
            for conn, _, raw in reader.messages(connections=conns):
                raws[conn.topic[len(ns):]].append(raw)
            decoded = {n: M.decode_topic(n, raws[n], stores[n]) for n in M.FIELDS if n in stores}
        return _episode(path, meta, decoded)


def topics_namespace(path: Path, topics: set[str]) -> str:
    """The namespace a bag's episode topics are under: "" for the contract's own names (every bag
    ``soil_bag_record`` writes, a namespaced graph's too), else the one namespace under which a
    machine's own recorder (``ros2 bag record`` of a graph in ``/dozer1``) wrote them all, e.g.
    ``/dozer1/blade/force``. BagReadError for a bag holding the episode topics of several
    namespaces (several machines' data: one machine per bag)."""
    required = [t.name for t in EPISODE_TOPICS if t.name not in (GROUND_TRUTH.name, CLOCK.name)]
    first = required[0]
    under = {name[: -len(first)] for name in topics if name.endswith(first)}  # ("" for the contract's own)
    whole = sorted(ns for ns in under if all(ns + name in topics for name in required))
    if len(whole) > 1:
        shown = ", ".join(ns or "the root namespace" for ns in whole)
        raise BagReadError(path, f"holds the episode topics of {len(whole)} namespaces ({shown}): several "
                                 "machines' data; a bag must hold one machine's")
    if whole and whole[0]:
        log.info("%s: reading the episode topics under the namespace %s", path, whole[0])
    return whole[0] if whole else ""


def _episode(path: Path, meta: EpisodeMeta, decoded: dict) -> Episode:
    """The Episode of a bag's decoded topics (``read_episode``): complete ticks, a machine's missing
    truth and clock filled in, its rate and force sign judged. A truth or clock channel without
    messages is none: a recorder subscribed to every episode topic of a replay that left them out
    (``soil_bag_play --exclude /soil/ground_truth``) writes their channels empty, and every reader
    had refused its own recorder's bag (an outside tester's)."""
    for name in (GROUND_TRUTH.name, CLOCK.name):
        if name in decoded and len(decoded[name][0]) == 0:
            decoded.pop(name)
            log.info("%s: topic %s has no messages: read as a bag without it", path, name)
    if empty := [n for n, (s, _) in decoded.items() if len(s) == 0]:
        raise BagReadError(path, f"topic {empty[0]} has no messages")
    # /clock carries no data: the ticks are the data topics' stamps (a machine's recorder may tick
    # /clock at its own rate or offset; aligned with them it was, and stays, one of them)
    decoded.pop(CLOCK.name, None)
    decoded = complete_ticks(path, decoded)
    stamps = np.unique(np.concatenate([s for s, _ in decoded.values()]))  # (duplicates are the topics' own)
    for name, fill in ((GROUND_TRUTH.name, np.nan), (CLOCK.name, 0.0)):
        if name not in decoded:
            decoded[name] = (stamps, np.full((len(stamps), M.FIELDS[name].width), fill))
    episode = M.assemble_episode(meta, decoded)
    if problem := rate_problem(episode.stamps_ns):
        raise BagReadError(path, problem)
    known = {n: episode.known[:, KNOWN_PARAMS.index(n)] for n in ("d", "v_x")}
    if problem := sign_problem(*cutting_ticks(episode.forces[:, 0], known["d"], known["v_x"])):
        log.warning("bag %s: %s", path, problem)
    return episode


# A bag whose ticks lack a topic in more than this share is not one stream of ticks (topics
# stamped each by its own clock): refused, not thinned to nothing.
MAX_INCOMPLETE_SHARE = 0.5


def complete_ticks(path: Path, decoded: dict) -> dict:
    """``decoded`` (topic -> (stamps, values)) at the ticks every topic has; a tick some topic lacks
    is dropped with a warning naming the topic and stamp (before, one lost message refused the whole
    bag, where the live estimator resets its window and goes on). Most ticks incomplete: BagReadError
    saying the topics' stamps do not line up (a machine's sensors stamping each by its own clock)."""
    stamps = {n: np.unique(s) for n, (s, _) in decoded.items()}
    every = np.unique(np.concatenate(list(stamps.values())))
    common = every
    for s in stamps.values():
        common = np.intersect1d(common, s, assume_unique=True)
    if len(common) == len(every):
        return decoded
    lacking = {n: np.setdiff1d(every, s, assume_unique=True) for n, s in stamps.items()}
    worst = max(lacking, key=lambda n: len(lacking[n]))
    example = f"e.g. {worst} has no message at {int(lacking[worst][0])} ns"
    if len(common) < (1.0 - MAX_INCOMPLETE_SHARE) * len(every):
        raise BagReadError(path, f"its topics' stamps do not line up: {len(every) - len(common)} of {len(every)} stamps "
                                 f"lack a topic ({example}); every topic of a tick must carry the tick's stamp (not "
                                 "each sensor's own clock): stamp them alike, or resample to common 60 Hz ticks")
    log.warning("bag %s: %d of %d ticks lack a topic (%s): dropped, a gap in the episode (the live estimator "
                "resets its window at one alike)", path, len(every) - len(common), len(every), example)
    out = {}
    for name, (s, values) in decoded.items():
        keep = np.isin(s, common)
        out[name] = (s[keep], values[keep])
    return out


def find_episode_bags(root: str | os.PathLike) -> list[Path]:
    """Sorted bag directories under ``root`` (or ``root`` itself); skips ``*.partial``. Symbolic
    links to directories are followed (a dataset assembled from links to recorded runs), each real
    directory once (a link back up the tree cannot loop)."""
    return scan_bags(root)[0]


def scan_bags(root: str | os.PathLike) -> tuple[list[Path], list[Path]]:
    """(``find_episode_bags(root)``, what under ``root`` no reader takes, sorted) in one walk, the
    second said to the user, since the bag search passes it by: a stray ``.mcap`` lies outside
    any rosbag2 directory (``metadata.yaml``) and any recorder journal, e.g. a bag's file copied
    without its directory; a recorder journal (a ``*.partial`` directory) is a killed recorder's,
    to be repaired (``soil_bag_repair``), or one still being written."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"dataset root {root} is not a directory")
    found: list[Path] = []
    strays: list[Path] = []
    seen: set[str] = set()
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        d = Path(dirpath)
        real = os.path.realpath(dirpath)
        if real in seen:
            dirnames.clear()
            continue
        seen.add(real)
        dirnames.sort()  # a bag reached by two links is found by the first in name order, on any file system
        if d.name.endswith(PARTIAL_SUFFIX):
            dirnames.clear()
        elif "metadata.yaml" in filenames:
            found.append(d)
            dirnames.clear()  # a bag holds no bags
        else:
            strays.extend(d / n for n in dirnames if n.endswith(PARTIAL_SUFFIX))
            dirnames[:] = [n for n in dirnames if not n.endswith(PARTIAL_SUFFIX)]
            strays.extend(d / f for f in filenames if f.endswith(".mcap"))
    return sorted(found), sorted(strays)


def passed_by_note(strays: list[Path], root: Path) -> str:
    """What the bag search passed by, for the user ("" if nothing): .mcap files outside any rosbag2
    directory, recorder journals (``*.partial``) with the command that repairs them (``scan_bags``'s
    second list under ``root``)."""
    def shown(paths):
        return ", ".join(str(p) for p in paths[:3]) + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")

    partials = [p for p in strays if p.name.endswith(PARTIAL_SUFFIX)]
    journals = [p for p in partials if journal_path(p).exists()]
    # (a bag's staging directory without a journal, left by a writer killed mid-write, e.g. a lost Ray
    # cluster's worker, had been named a recorder journal to repair)
    parked = [p for p in partials if p not in journals and (p / "replaced").exists()]  # an --overwrite's old bag
    unfinished = [p for p in partials if p not in journals and p not in parked]
    files = [p for p in strays if p not in partials]
    notes = []
    if files:
        from .bag_salvage import embedded_metadata  # (it reads bags through this module)

        # the repair rebuilds a lost metadata.yaml from the file's own rosbag2 record; a bag rosbag2
        # itself was stopped in has none (it had been sent to the repair all the same, which then found
        # nothing to rebuild from: an outside tester's). Judged by the files shown (a stopped writer's
        # file has no index: reading its records is a scan of the whole file).
        own = [embedded_metadata(f) is not None for f in files[:3]]
        reindex = "`ros2 bag reindex DIR`, on a ROS install, rebuilds it from the messages"
        hint = ("soil_bag_repair DIR copies it with one rebuilt from the file's own record" if all(own) else
                f"the file(s) shown carry no record of it (a bag `ros2 bag record` was stopped before writing it): {reindex}"
                if not any(own) else f"soil_bag_repair DIR copies one whose file carries its own record (of those shown "
                f"{', '.join(str(f) for f, o in zip(files, own) if o)}) with one rebuilt from it; for the others {reindex}")
        notes.append(f"not read: {len(files)} .mcap file(s) outside a rosbag2 bag directory (its metadata.yaml "
                     f"beside the .mcap): {shown(files)}; where that is a bag whose metadata.yaml was lost, {hint}")
    if journals:
        notes.append(f"not read: {len(journals)} recorder journal(s), a killed recorder's or one still being "
                     f"written: {shown(journals)}; soil_bag_repair {root} turns a killed recorder's into bags")
    if unfinished:
        notes.append(f"not read: {len(unfinished)} unfinished bag write(s), a writer stopped mid-write or one still "
                     f"writing: {shown(unfinished)}; nothing to recover (the next soil_sim_batch writing that bag "
                     "removes it, or delete it)")
    if parked:
        notes.append(f"not read: {len(parked)} old bag(s) parked by an overwrite that stopped midway: {shown(parked)}; "
                     "its 'replaced' directory is the old bag: move it back beside them under the bag's name to keep it")
    return "; ".join(notes)


def read_dataset(root: str | os.PathLike, *, progress: bool = False) -> list[Episode]:
    """Every episode bag under ``root``, in path order."""
    bags = find_episode_bags(root)
    if not bags:
        raise ValueError(f"no bags found under {root}")
    if progress:
        from tqdm import tqdm

        bags = tqdm(bags, desc="reading bags", unit="bag")
    return [read_episode(b) for b in bags]


def read_labelled_topic(bag_dir: str | os.PathLike, topic: str, labels: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(stamps int64 (n,), values float64 (n, len(labels))) of a labelled-array topic in a bag,
    in log order (e.g. the ``/soil/estimate`` a live estimator published during the episode); a
    layout of before fields were added is read with the fields it lacks 0 (``messages.parse_labelled``).

    BagReadError if the bag lacks the topic, a message has another layout or the bag is damaged."""
    path = Path(bag_dir)
    stamps, rows = [], []
    with reading(path), AnyReader([path], default_typestore=M.TYPESTORE) as reader:
        ns = topics_namespace(path, {c.topic for c in reader.connections})
        conns = [c for c in reader.connections if c.topic == ns + topic]
        if not conns:
            raise BagReadError(path, f"has no topic {ns + topic}")
        for conn, _, raw in reader.messages(connections=conns):
            stamp, values = M.parse_labelled(reader.deserialize(raw, conn.msgtype), labels, topic)
            stamps.append(stamp)
            rows.append(values)
    values = np.stack(rows) if rows else np.empty((0, len(labels)))
    return np.asarray(stamps, dtype=np.int64), values
