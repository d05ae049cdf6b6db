"""What a cut achieved (pure NumPy over a ``cut_trial.Cut``): soil moved, stalls, force use.

* **Volume cut** [m³]: the heightfield below the original level surface z = 0 after the cut,
  times the blade width, over the cells the edge crossed (the simulator lowers a cell to the
  edge height when the edge passes it). Per metre: over the edge's travel; per second: over
  the cut's duration.
* **Stall time** [s]: ticks with the chassis speed below the anti-stall controller's
  threshold v̄_x (1 − c_vx) (where its Eq. 11 lift starts acting), counted from the first
  tick the machine reached that speed (the start from rest is not a stall).
* **Ticks at a force limit**: measured |F_x| or |F_z| at or above ``AT_LIMIT`` of the
  20 kN tractive / 30 kN lift limit (the motor and the lift joint saturate there).
* **Back-off events**: the controller's anti-stall offset Δd̄ leaving zero (it starts lifting).
* **Target falls**: how often the controller's target depth fell by at least ``FALL_M`` from
  its deepest since it last rose (a fixed depth has none; one long fall counts once; a planner
  that cycles between a depth and a shallower one has one per cycle). The depth schedule's own
  "retreat" (``soil_planner.depth_schedule``) is a plan below the target, which starts a fall.
* **Force use**: mean and 95th percentile of |F_x| / 20 kN and |F_z| / 30 kN while cutting.
* **Per patch**: time in it, mean target and cut depth, stall time; the best fixed depth in
  hindsight is, of a sweep of fixed depths at which no stall began in that patch (a stall is the
  soil's where it began), among those whose edge entered its soil, the shallowest that cut it
  within 5 mm as deep as any (``judged_depths``), the share of its time the
  target lay within ``SETTLE_TOLERANCE`` of it (``within_share``), and ``settle_s`` how long after entering the patch the target
  came within ``SETTLE_TOLERANCE`` of it and stayed there for ``SETTLE_HOLD_S``.
"""
from __future__ import annotations

import numpy as np

from anti_stall_controller.controller import limit_shares
from soil_msgs_py.params import MIN_CUT_DEPTH_M, SAMPLE_RATE_HZ, stall_speed_m_s, ticks_in

AT_LIMIT = 0.98
BACKOFF_ON_M = 1e-3  # an offset above this counts as the controller lifting
SETTLE_TOLERANCE = 0.20  # relative to the patch's best fixed depth
SETTLE_HOLD_S = 1.0
FALL_M = 0.02  # a target falling this far from its deepest since it last rose is a fall
SAME_CUT_M = 0.005  # fixed depths whose edge cut a patch this close to the deepest one's cut it alike (judged_depths)


def stall_mask(cut) -> np.ndarray:
    """Ticks below the controller's threshold speed, from the first tick at that speed on."""
    slow = cut.v_x < stall_speed_m_s(cut.target_speed_m_s, cut.gains.c_vx)
    reached = np.flatnonzero(~slow)
    if len(reached) == 0:
        return slow
    slow[: reached[0]] = False
    return slow


def volume_m3(cut) -> float:
    """Soil cut below z = 0 [m³]: Σ max(0, −z_cell) · cell · w over the cells the edge crossed."""
    x = cut.x_min_m + cut.cell_m * (np.arange(len(cut.terrain)) + 0.5)
    crossed = (x >= np.nanmin(cut.x_b)) & (x <= np.nanmax(cut.x_b))
    return float(np.clip(-cut.terrain[crossed], 0.0, None).sum() * cut.cell_m * cut.width_m)


def run_starts(mask: np.ndarray) -> np.ndarray:
    """Indices where a run of True in ``mask`` (ticks) begins, a True first tick included."""
    return np.flatnonzero(mask & ~np.concatenate([[False], mask[:-1]]))


def backoff_events(cut) -> int:
    return len(run_starts(cut.offset > BACKOFF_ON_M))


def target_falls(target_m: np.ndarray, fall_m: float = FALL_M) -> int:
    """Times a target depth series [m] fell by at least ``fall_m`` [m] below its deepest since it
    last rose: a fall is counted once however long it goes on, and the next needs the target to
    have deepened again (by any amount) first."""
    target_m = np.asarray(target_m, float)
    n, peak, low, falling = 0, -np.inf, np.inf, False
    for t in target_m[np.isfinite(target_m)]:
        if falling:
            if t > low:  # deepening again: a new peak
                falling, peak = False, t
            low = min(low, t)
        elif t > peak:
            peak = t
        elif peak - t >= fall_m - 1e-12:
            n, falling, low = n + 1, True, t
    return n


def summary(cut) -> dict:
    """The policy's figures over the whole cut (SI; module docstring)."""
    dt = 1.0 / SAMPLE_RATE_HZ
    travel = float(cut.x_b[-1] - cut.x_b[0])
    volume = volume_m3(cut)
    share = limit_shares(cut.force)
    cutting = cut.depth > 0.0
    use = share[cutting] if cutting.any() else np.zeros((1, 2))
    return {
        "policy": cut.policy.name, "fixed_depth_m": cut.policy.fixed_depth_m,
        "duration_s": cut.ticks * dt, "travel_m": travel, "volume_m3": volume,
        "volume_per_m_m3": volume / travel if travel > 0 else 0.0, "volume_per_s_m3": volume / (cut.ticks * dt),
        "stall_s": float(stall_mask(cut).sum() * dt), "ticks_at_limit": int(np.count_nonzero((share >= AT_LIMIT).any(axis=1))),
        "backoff_events": backoff_events(cut), "target_falls": target_falls(cut.target),
        "force_x_mean_share": float(use[:, 0].mean()), "force_x_p95_share": float(np.percentile(use[:, 0], 95)),
        "force_z_mean_share": float(use[:, 1].mean()), "force_z_p95_share": float(np.percentile(use[:, 1], 95)),
        "mean_depth_m": float(cut.depth[cutting].mean()) if cutting.any() else 0.0,
    }


def entered(cut, j: int) -> bool:
    """Whether the edge cut patch ``j``'s soil in ``cut``: deeper than MIN_CUT_DEPTH_M there on
    average. A soil whose bearing capacity holds the lift's push keeps the edge on its surface at
    every target depth, and there a target says nothing of the depth cut."""
    inside = cut.patch == j
    return bool(inside.any() and cut.depth[inside].mean() > MIN_CUT_DEPTH_M)


def stall_starts(cut) -> np.ndarray:
    """The ticks at which a stall began (the first tick of each of ``stall_mask``'s runs)."""
    return run_starts(stall_mask(cut))


def stall_free_cuts(sweep: list, n_patches: int) -> list[list[tuple[float, float]]]:
    """Per patch, (fixed depth, mean depth the edge cut there) of the cuts of ``sweep`` (one path)
    in which no stall began while the edge was in that patch, of those whose edge cut its soil
    (``entered``). A stall is its soil's where it began: one that began in dense clay and ran on a
    few ticks past the boundary into the loam after it says nothing about the loam (counted there,
    it made the loam's best depth 0.150 m where no stall began in the loam at any depth shallower
    than 0.225 m, seed 5 of the main path)."""
    ok: list[list[tuple[float, float]]] = [[] for _ in range(n_patches)]
    for cut in sweep:
        began_in = set(cut.patch[stall_starts(cut)].tolist())
        for j in range(n_patches):
            if entered(cut, j) and j not in began_in:
                ok[j].append((cut.policy.fixed_depth_m, float(cut.depth[cut.patch == j].mean())))
    return ok


def deepest_stall_free(candidates: list[list[tuple[float, float]]]) -> list[float | None]:
    """Per patch of ``stall_free_cuts``, the deepest fixed depth (None: a stall began there at every
    depth, or none entered it): what the conservative and aggressive policies keep."""
    return [max(fixed for fixed, _ in cuts) if cuts else None for cuts in candidates]


def judged_depths(candidates: list[list[tuple[float, float]]]) -> list[float | None]:
    """Per patch of ``stall_free_cuts``, the best fixed depth a planner is judged against: the
    shallowest whose edge cut the patch within ``SAME_CUT_M`` of the deepest cut of them. Where the
    floor holds the edge short of its target (a dense gravel in the default world) every target from
    0.125 m to 0.300 m cut 0.12 m, and "best 0.300 m" (an outside tester's) made a planner cutting
    0.12 m there look 2.5x too shallow."""
    best: list[float | None] = []
    for cuts in candidates:
        deepest_cut = max((depth for _, depth in cuts), default=None)
        best.append(None if deepest_cut is None else
                    min(fixed for fixed, depth in cuts if depth >= deepest_cut - SAME_CUT_M))
    return best


def best_fixed_depths(sweep: list, n_patches: int, *, same_cut: bool = False) -> list[float | None]:
    """Per patch, the deepest stall-free fixed depth of ``sweep`` (``deepest_stall_free``), or with
    ``same_cut`` the one a planner is judged against (``judged_depths``)."""
    candidates = stall_free_cuts(sweep, n_patches)
    return judged_depths(candidates) if same_cut else deepest_stall_free(candidates)


def settle_s(cut, j: int, best_m: float | None) -> float | None:
    """Seconds from entering patch ``j`` until the target stayed within SETTLE_TOLERANCE of
    ``best_m`` for SETTLE_HOLD_S (or to the patch's end); None if it never did."""
    inside = np.flatnonzero(cut.patch == j)
    if best_m is None or len(inside) == 0:
        return None
    target = cut.target[inside]
    ok = np.abs(target - best_m) <= SETTLE_TOLERANCE * best_m
    hold = ticks_in(SETTLE_HOLD_S)
    for i in range(len(ok)):
        window = ok[i: i + hold]
        if window.all() and (len(window) == hold or i + len(window) == len(ok)):
            return i / SAMPLE_RATE_HZ
    return None


def within_share(cut, j: int, best_m: float | None) -> float | None:
    """The share of patch ``j``'s ticks whose target lay within SETTLE_TOLERANCE of ``best_m``
    (None: no best there). Beside ``settle_s``: a target within it for a second at the patch's
    entry, carried over from the patch before, "settled" there and may leave it for good after
    (an outside tester's dense gravel: settled after 0.0 s, the mean target 0.179 m for 0.250 m)."""
    inside = cut.patch == j
    if best_m is None or not inside.any():
        return None
    return float(np.mean(np.abs(cut.target[inside] - best_m) <= SETTLE_TOLERANCE * best_m))


def per_patch(cut, best: list[float | None]) -> list[dict]:
    """Per patch of the path: time, mean target and cut depth, stall time, hindsight best, settle time.
    The stall time is the ticks stalled while the edge was in the patch (where the machine stood
    still); which depth is best counts a stall in the patch where it began (``stall_free_cuts``)."""
    dt = 1.0 / SAMPLE_RATE_HZ
    stalled = stall_mask(cut)
    rows = []
    for j, patch in enumerate(cut.spec.patches or (None,)):
        inside = cut.patch == j
        best_m = best[j] if j < len(best) else None
        rows.append({
            "patch": j, "soil": patch.soil if patch else cut.spec.soil,
            "x_start_m": patch.x_start_m if patch else float(cut.x_b[0]),
            "relative_density_pct": patch.relative_density_pct if patch else cut.spec.relative_density_pct,
            "time_s": float(inside.sum() * dt),
            "mean_target_m": float(cut.target[inside].mean()) if inside.any() else None,
            "mean_depth_m": float(cut.depth[inside].mean()) if inside.any() else None,
            "stall_s": float((stalled & inside).sum() * dt),
            "best_fixed_depth_m": best_m,
            "settle_s": settle_s(cut, j, best_m),
            "within_share": within_share(cut, j, best_m),
        })
    return rows
