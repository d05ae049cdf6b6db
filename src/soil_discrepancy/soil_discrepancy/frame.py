"""The analysed ticks of a measured dataset: blade in soil, after the start transient, per θ-group.

A θ-group is the episodes that dug the same soil (same soil name and relative density in the
bag metadata), or every episode on its own (``group_by="episode"``), or the episodes whose
measured soil unit weight γ (a known parameter Θ_k carries) is the same (``group_by="gamma"``;
also the default for bags without any soil label, such as a real machine's, when γ makes at
least three groups): one soil θ = (φ, c, δ) is fitted per group (``fee_fit``). Nothing here reads
the simulator's ground truth (``Dataset.truth``) or the bag metadata's record of which effects/plugins were switched on: only Θ_k, the measured force,
the blade's velocities (observations), time and the soil name / relative density used as a grouping label. SI units.

The force analysed is the soil's: the measured force minus the blade's own inertia m_b·a
(``soil_physics.blade_inertia``, the tick-mean acceleration from consecutive velocities; none
across a gap of a repaired bag), as the fused posterior takes it. A model of the soil explains
no inertia: left in, it is a residual wherever the blade accelerates vertically (the fee world's
F_z while the edge sinks), which the form search then names as if it were soil physics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pinn_estimator.forecast import episode_one_soil
from soil_msgs_py.episode import world_modes
from soil_msgs_py.soil_labels import UNKNOWN_SOIL, gamma_group_names, soil_label
from soil_msgs_py.params import KNOWN_PARAMS, MIN_CUT_DEPTH_M, OBSERVATION_FIELDS, SAMPLE_RATE_HZ
from soil_physics.blade_inertia import inertia_rows
from soil_physics.travel import distance_in_soil_of_known, time_in_soil_of_known

MIN_DEPTH_M = MIN_CUT_DEPTH_M  # ticks with the blade in the soil deeper than this are analysed
SKIP_S = 1.0  # the start transient (blade entering the soil) is left out
DEFAULT_STRIDE = 2  # every second tick in the soil: neighbouring ticks at 60 Hz tell little new
GROUP_BY = ("auto", "episode", "gamma")
# An episode with less analysed cutting than this is left out: a fit of its soil to a few ticks (a
# blade that barely entered a rock) says nothing, and a verdict drawn from such episodes would be
# one of low power stated as "no significant discrepancy". One PINN window.
MIN_CUT_S = 1.0
MAX_STRIDE = SAMPLE_RATE_HZ  # ticks between analysed ticks: at least one a second of cutting (MIN_CUT_S)
# group_by="auto" on bags without any soil label groups by γ only if that gives at least this many
# groups: the workflow holds out groups and cross-validates over the rest (``split_holdout``).
MIN_GAMMA_GROUPS = 3
_KI = {n: i for i, n in enumerate(KNOWN_PARAMS)}


@dataclass
class Frame:
    """The analysed ticks (blade in soil, after the start transient, every ``stride``-th).

    Episode-level arrays have length E (all episodes of the dataset, global indices); tick
    arrays length N. ``rows`` are the ticks' global row indices in the ``Dataset`` (for a PINN
    to predict at exactly these ticks; with ``skip_s`` >= 59/60 s each has a full 60-tick window).
    """

    names: list[str]
    soils: list[str]  # metadata soil name per episode ('unknown' if the bag does not say)
    densities: list[float]  # metadata relative density [%] per episode (NaN if unknown)
    group_of: np.ndarray  # (E,) θ-group index per episode
    group_names: list[str]
    episode: np.ndarray  # (N,) episode index per tick
    rows: np.ndarray  # (N,) row in the Dataset
    t: np.ndarray  # (N,) time since the episode started [s]
    known: np.ndarray  # (N, 9) Θ_k [SI]
    forces: np.ndarray  # (N, 2) the soil's force: measured minus the blade's inertia m_b·a [N]
    distance: np.ndarray  # (N,) blade travel in soil since the start [m]
    time_in_soil: np.ndarray  # (N,) time with the blade in the soil since the start [s]
    inertia: np.ndarray  # (N, 2) the blade's inertia m_b·a the measured force held beside ``forces`` [N]
    stride: int = 1
    group_by: str = "auto"
    source: str = ""
    changing_soil: tuple[str, ...] = ()  # episodes left out: their metadata says the soil changes along the path
    # episodes without a soil label beside labelled ones, grouped by their measured γ (``build_frame``)
    unlabelled_by_gamma: tuple[str, ...] = ()
    too_short: tuple[str, ...] = ()  # episodes left out: less than MIN_CUT_S of analysed cutting
    # episodes left out: each a copy of another analysed one (the noise-free fee world's seeds, a replay
    # recorded again), which would count one episode's evidence twice (``copies_of``)
    copies: tuple[str, ...] = ()
    # θ-group -> (lo, hi) SI (φ [rad], c [Pa], δ [rad]; ±inf: free) where soil tests hold θ (``soil_tests``)
    theta_boxes: dict | None = None
    # (E,) where along the path each episode's travel in soil began [m]: the median of x_b − s over its
    # analysed ticks (NaN: none analysed); ``regimes.travel_is_position``
    entry_x_m: np.ndarray | None = None
    # at stride > 1, per axis: RMS [N] of the soil's force about the mean of each block of ``stride``
    # ticks ("within"), of its change from one analysed tick to the next as white noise would give it
    # ("between", ``regimes.fast_part``'s measure); the RMS of |F| ("force"), the "stride" and the
    # number of analysed-tick "pairs" behind "between": ``folded_rms``, ``folded_vibration``
    fast_force: dict | None = None

    def __len__(self) -> int:
        return len(self.episode)

    @property
    def group(self) -> np.ndarray:
        """(N,) θ-group index per tick."""
        return self.group_of[self.episode]

    @property
    def episodes(self) -> np.ndarray:
        """Episode indices present (sorted)."""
        return np.unique(self.episode)

    @property
    def groups(self) -> np.ndarray:
        return np.unique(self.group)

    def episode_names(self, groups=None) -> list[str]:
        """Names of the episodes present (in episode order), only those of ``groups`` if given."""
        keep = None if groups is None else {int(g) for g in groups}
        return [self.names[int(e)] for e in self.episodes if keep is None or int(self.group_of[e]) in keep]

    def select(self, *, episodes=None, groups=None) -> "Frame":
        """The ticks of some episodes or θ-groups (global indices kept)."""
        mask = np.ones(len(self), bool)
        if episodes is not None:
            mask &= np.isin(self.episode, np.asarray(list(episodes), int))
        if groups is not None:
            mask &= np.isin(self.group, np.asarray(list(groups), int))
        return self.subset(mask)

    def subset(self, mask: np.ndarray) -> "Frame":
        """The ticks where ``mask`` (N,) is True (episode-level arrays and global indices kept)."""
        return replace(self, episode=self.episode[mask], rows=self.rows[mask], t=self.t[mask],
                       known=self.known[mask], forces=self.forces[mask], distance=self.distance[mask],
                       time_in_soil=self.time_in_soil[mask], inertia=self.inertia[mask])

    def column(self, name: str) -> np.ndarray:
        """A per-tick variable: a Θ_k name, 't', 'distance' or 'time_in_soil'."""
        if name == "t":
            return self.t
        if name == "distance":
            return self.distance
        if name == "time_in_soil":
            return self.time_in_soil
        return self.known[:, _KI[name]]

    def has_metadata(self) -> bool:
        """Whether an analysed episode has a soil label (a left-out one's says nothing here)."""
        return any(self.soils[e] != UNKNOWN_SOIL for e in self.episodes)


def density_label(relative_density_pct: float) -> str:
    """A relative density [%] as θ-groups, soil tests and the misfit test's rows name it: "I_d=0%"."""
    return f"I_d={relative_density_pct:g}%"


def _gamma_groups(ds, episodes) -> list[str]:
    """Per episode, the name of its γ-group (``soil_labels.gamma_group_names``) over the median γ of
    ``episodes`` (those analysed: a left-out episode's γ must not bridge two chains); "" for the rest."""
    episodes = sorted(int(e) for e in episodes)
    gamma = np.array([float(np.median(np.asarray(ds.known[ds.episode_rows(e)], float)[:, _KI["gamma"]]))
                      for e in episodes])
    if not np.isfinite(gamma).all():
        bad = ds.names[episodes[int(np.flatnonzero(~np.isfinite(gamma))[0])]]
        raise ValueError(f"episode {bad}: gamma is not finite; cannot group by it")
    out = [""] * len(ds.names)
    for e, name in zip(episodes, gamma_group_names(gamma)):
        out[e] = name
    return out


def check_frame_settings(stride, group_by: str) -> None:
    """ValueError naming ``stride`` (ticks, an integer >= 1) or ``group_by`` if it cannot make a frame."""
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or not 1 <= stride <= MAX_STRIDE:
        raise ValueError(f"stride={stride!r} must be an integer in [1, {MAX_STRIDE}] ticks (at least one analysed tick "
                         "a second of cutting: the regime and held-out tests compare ticks within episodes)")
    if group_by not in GROUP_BY:
        raise ValueError(f"group_by={group_by!r} must be one of {GROUP_BY}")


def copies_of(ds) -> set[int]:
    """The episodes of ``ds`` that are copies of another (``pinn_estimator.dataset.identical_episodes``:
    the same metadata but the seed, the same samples), all but the longest of each set (the first
    by name of equals). Why: in the noise-free fee world the seeds of one grid point are one
    episode, and analysed as many they counted its evidence as many times (an outside tester's
    grid of two seeds named a speed effect on one target speed, its p over 16 episodes of 8)."""
    from pinn_estimator.dataset import identical_episodes

    index = {name: e for e, name in enumerate(ds.names)}
    length = np.diff(ds.offsets)  # ticks per episode
    out = set()
    for names in identical_episodes(ds):
        members = sorted((index[n] for n in names), key=lambda e: (-length[e], ds.names[e]))
        out.update(members[1:])
    return out


def build_frame(ds, *, stride: int = DEFAULT_STRIDE, min_depth_m: float = MIN_DEPTH_M, skip_s: float = SKIP_S,
                group_by: str = "auto") -> Frame:
    """Analysis ticks of a ``pinn_estimator.dataset.Dataset`` (never touches ``ds.truth``).

    group_by: 'auto' — episodes with the same metadata soil name and relative density share θ
    (episodes without a soil label beside labelled ones share θ by their measured γ, named in
    ``unlabelled_by_gamma``; one whose γ is not finite is its own group); when no episode has a soil label, as
    'gamma' if measured γ makes at least ``MIN_GAMMA_GROUPS`` groups, fewer than the episodes
    (one θ per episode would hide every effect that is constant within an episode), else as
    'episode'; the frame's ``group_by`` says which was used. 'episode' — one θ per episode;
    'gamma' — episodes with the same measured unit weight γ share θ (no label read; two soils
    of one γ share a θ, which the report's regimes then show as a misfit).

    Episodes with less than ``MIN_CUT_S`` of analysed cutting are left out (``too_short``).
    Episodes whose edge crossed soil patches (of their metadata) of more than one soil or density are
    left out (named in ``changing_soil``): one θ cannot hold across a soil change, and a fit across it
    reads the change as missing physics (the forecast leaves them out alike, ``forecast.one_soil``). A bag
    that does not record its path (a machine's) is taken as one soil.
    """
    check_frame_settings(stride, group_by)
    n_ep = len(ds.names)
    if n_ep == 0:
        raise ValueError("the dataset has no episodes")
    worlds = world_modes(ds.metas)
    if len(worlds) > 1:
        raise ValueError(f"the dataset mixes worlds {worlds} (bag metadata world_mode): a discrepancy is one "
                         "world's against the model; give one world's bags")
    changing = [e for e in range(n_ep) if not episode_one_soil(ds, e)]
    copies = copies_of(ds)
    if len(changing) == n_ep:
        raise ValueError(f"every one of the {n_ep} episode(s) changes soil along its path (soil patches in its "
                         "metadata): one θ per soil cannot be fitted across a change; give episodes of one soil each")
    dt = 1.0 / SAMPLE_RATE_HZ
    soils = [soil_label(m) for m in ds.metas]
    dens = []
    for m in ds.metas:
        try:
            v = float(m.relative_density_pct)
        except (TypeError, ValueError, AttributeError):
            v = math.nan
        dens.append(v if math.isfinite(v) else math.nan)
    parts = {k: [] for k in ("episode", "rows", "t", "known", "forces", "distance", "time_in_soil", "inertia")}
    short: list[int] = []
    entry_x = np.full(n_ep, np.nan)
    fast = _FastForce(stride)
    for e in range(n_ep):
        r = ds.episode_rows(e)
        known = np.asarray(ds.known[r], float)
        observations = np.asarray(ds.observations[r], float)
        inertia = inertia_rows(observations, ds.gap_before[r])
        forces = np.asarray(ds.forces[r], float) - inertia
        n = len(known)
        t = np.arange(n) * dt
        dist = distance_in_soil_of_known(known, dt)
        in_soil_s = time_in_soil_of_known(known, dt)
        cutting = np.nonzero((known[:, _KI["d"]] > min_depth_m) & (t >= skip_s - 1e-9))[0]
        keep = cutting[::stride]
        if e in changing or e in copies:
            keep = keep[:0]
        elif len(cutting) < MIN_CUT_S * SAMPLE_RATE_HZ:
            short.append(e)
            keep = keep[:0]
        elif stride > 1:
            fast.add(forces, cutting, stride)
        if len(keep):
            entry_x[e] = float(np.median(observations[keep, OBSERVATION_FIELDS.index("p_x_b")] - dist[keep]))
        parts["episode"].append(np.full(len(keep), e))
        parts["rows"].append(r.start + keep)
        parts["t"].append(t[keep])
        parts["known"].append(known[keep])
        parts["forces"].append(forces[keep])
        parts["inertia"].append(inertia[keep])
        parts["distance"].append(dist[keep])
        parts["time_in_soil"].append(in_soil_s[keep])
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    if len(cat["episode"]) == 0:
        raise ValueError(
            f"no episode of the {n_ep} has {MIN_CUT_S:g} s of the blade in the soil (d > {min_depth_m} m) after the "
            f"first {skip_s:g} s: nothing to compare the model with"
        )
    analysed = set(int(e) for e in np.unique(cat["episode"]))
    gamma_keys = None
    if group_by == "gamma":
        gamma_keys = _gamma_groups(ds, analysed)
    elif group_by == "auto" and all(soils[e] == UNKNOWN_SOIL for e in analysed):
        # γ groups only where they can be held out and cross-validated: counted over the episodes
        # with analysed ticks (a left-out episode's label decides nothing); a non-finite γ (no
        # grouping by it) falls back to one θ per episode
        try:
            gamma_keys = _gamma_groups(ds, analysed)
        except ValueError:
            pass
        n_gamma = len({gamma_keys[e] for e in analysed}) if gamma_keys is not None else 0
        group_by = "gamma" if MIN_GAMMA_GROUPS <= n_gamma < len(analysed) else "episode"
    unlabelled = sorted(e for e in analysed if soils[e] == UNKNOWN_SOIL)
    if group_by == "auto" and unlabelled and len(unlabelled) < len(analysed):
        # a folder mixing labelled bags with a machine's unlabelled ones: one θ per unlabelled
        # episode would take in every effect constant within an episode (the hidden soil inertia
        # of a test went unnamed so); grouped by measured γ as the forecast pairs them
        try:
            gamma_keys = _gamma_groups(ds, unlabelled)
        except ValueError:  # a non-finite γ: one θ per such episode, as before
            gamma_keys = None
    if group_by == "gamma":  # as bags without a soil label: the metadata's soil and I_d are not read
        soils, dens = [UNKNOWN_SOIL] * n_ep, [math.nan] * n_ep
    keys, group_names, group_of = {}, [], np.zeros(n_ep, int)
    by_gamma: list[str] = []  # unlabelled episodes beside labelled ones, grouped by γ
    for e in range(n_ep):
        if group_by == "gamma":
            key = gamma_keys[e] or ds.names[e]  # (a left-out episode: a group of its own, with no ticks)
        elif group_by == "auto" and soils[e] != UNKNOWN_SOIL:
            key = f"{soils[e]} {density_label(dens[e])}" if math.isfinite(dens[e]) else soils[e]
        elif group_by == "auto" and gamma_keys is not None and gamma_keys[e]:
            key = f"{UNKNOWN_SOIL} {gamma_keys[e]}"
            by_gamma.append(ds.names[e])
        else:
            key = ds.names[e]
        if key not in keys:
            keys[key] = len(group_names)
            group_names.append(key)
        group_of[e] = keys[key]
    return Frame(
        names=list(ds.names), soils=soils, densities=dens, group_of=group_of, group_names=group_names,
        episode=cat["episode"].astype(int), rows=cat["rows"].astype(np.int64), t=cat["t"],
        known=cat["known"].reshape(-1, len(KNOWN_PARAMS)), forces=cat["forces"].reshape(-1, 2), inertia=cat["inertia"].reshape(-1, 2),
        distance=cat["distance"], time_in_soil=cat["time_in_soil"], stride=stride, group_by=group_by, source=str(getattr(ds, "root", "")),
        changing_soil=tuple(ds.names[e] for e in changing), too_short=tuple(ds.names[e] for e in short),
        copies=tuple(ds.names[e] for e in sorted(copies)),
        unlabelled_by_gamma=tuple(by_gamma), entry_x_m=entry_x, fast_force=fast.result(),
    )


class _FastForce:
    """Sums for ``Frame.fast_force`` over the analysed episodes' cutting ticks."""

    def __init__(self, stride: int):
        self.within, self.between, self.force = np.zeros(2), np.zeros(2), 0.0
        self.n_within = self.n_between = 0
        self.stride = stride

    def add(self, forces: np.ndarray, cutting: np.ndarray, stride: int) -> None:
        f = forces[cutting]
        blocks = len(f) // stride  # whole blocks: the tick kept and the stride - 1 after it
        if blocks < 2:
            return
        b = f[:blocks * stride].reshape(blocks, stride, 2)
        if not np.isfinite(b).all():
            return  # (a NaN force: the episode adds nothing rather than counting blocks it cannot sum)
        self.within += ((b - b.mean(axis=1, keepdims=True)) ** 2).sum(axis=(0, 1))
        self.n_within += blocks * stride
        kept = b[:, 0]
        self.between += (np.diff(kept, axis=0) ** 2).sum(axis=0) / 2.0
        self.n_between += blocks - 1
        self.force += float((b ** 2).sum())

    def result(self) -> dict | None:
        if not self.n_within or not self.n_between:
            return None
        within, between = np.sqrt(self.within / self.n_within), np.sqrt(self.between / self.n_between)
        return {"within": {"x": float(within[0]), "z": float(within[1])},
                "between": {"x": float(between[0]), "z": float(between[1])},
                "force": math.sqrt(self.force / self.n_within), "stride": self.stride, "pairs": self.n_between}


# White noise's share is estimated from the pairs of analysed ticks: what varies within the blocks
# must exceed it by this many of that estimate's standard errors (sqrt(2 / pairs) of it) to count
# (2000 N of white noise on the 32-episode grid left 400 N "beyond noise" at stride 8 without it).
FOLD_SIGMAS = 3.0


def folded_rms(fast: dict, axis: str) -> float:
    """The RMS [N] of what varies within the blocks beyond white noise's share (``Frame.fast_force``):
    sqrt(within² − (s − 1)/s · between² − its sampling margin), 0 if none. White noise gives
    (s − 1)/s of its variance within and all of it between, so it cancels; slow physics changes more
    between analysed ticks than within a block, so it gives none; a vibration near a multiple of
    60 Hz / s varies within the blocks and folds to a slow signal between them. (A plain ratio of the
    two missed an outside reviewer's chatter in the default world, whose noise and particle events
    fill "between".)"""
    s = fast["stride"]
    noise = (s - 1) / s * fast["between"][axis] ** 2
    margin = FOLD_SIGMAS * noise * math.sqrt(2.0 / max(fast["pairs"], 1))
    return math.sqrt(max(fast["within"][axis] ** 2 - noise - margin, 0.0))


def folded_vibration(frame: Frame, min_share: float) -> list[str]:
    """The axes on which analysing every ``frame.stride``-th tick folds a vibration into a slow signal.

    The force varies within the blocks of ``stride`` ticks, beyond what white noise does, by at least
    ``min_share`` of |F| (``folded_rms``): fast content the decimation does not see as fast.
    An outside reader's 29.9 Hz chatter, analysed every 2nd tick, was a 0.1 Hz signal, named as a
    slow relief growing with time in soil and "pinned down"; analysed every tick it is "alternating
    from tick to tick"."""
    fast = frame.fast_force
    if frame.stride <= 1 or not fast or not fast["force"]:
        return []
    return [a for a in ("x", "z")
            if folded_rms(fast, a) >= min_share * fast["force"]]
