"""What the default world's vertical force is: the lift's push carried by the floor, not soil failure.

The discrepancy workflow leaves the default world "unexplained", and its held-out error is mostly
F_z. This prints, on the same 108-episode grid as ``make discrepancy`` (generated here if absent),
how much of the z residual of the FEE **at the true soil** (ground truth: a benchmark may read it,
the workflow never does) each kind of explanation reaches, as R² over the analysed ticks (blade
deeper than 1 cm, after the first 1 s):

1. the lift's own spring-damper on its command error u_zr − (p_z_b − p_z_c) and its rate
   v_z_b − v_z_c, plus a constant: the measured F_z *is* the lift joint's force (less the tared
   weight), so this is a regression of the force on itself through the lift's stiffness. Its
   coefficients are the machine's, not the soil's.
2. forms built from the soil state only (what a model gets from Θ_k): the edge's bearing
   capacity, always and while sinking, and saturating with speed.
3. the same with the gate "lift commanded below the edge" (a machine signal, but again the sign
   of the measured F_z beyond the blade's weight).

And, per soil and I_d at 0.1 m, the steady (second half) measured F_z against the bearing
capacity at the true soil. Asserts nothing.

    .venv/bin/python benchmarks/bench_floor_reaction.py [--bags bags/disc_full/default_world]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from pinn_estimator.dataset import load_dataset  # noqa: E402
from soil_msgs_py.params import GROUND_TRUTH_PARAMS, KNOWN_PARAMS, OBSERVATION_FIELDS, SAMPLE_RATE_HZ  # noqa: E402
from soil_physics.augmented_fee import fee_forces  # noqa: E402
from soil_physics.bearing import EDGE_WIDTH_M, penetration_capacity  # noqa: E402
from soil_physics.term_forms import VZ_GATE_M_S  # noqa: E402

GRID = ["--relative-densities", "0,40,80", "--speeds", "0.3,0.65,1.0", "--depths", "0.1,0.175,0.25",
        "--seeds", "1", "--seed-base", "100", "--quiet", "--mode", "default"]


def r2(columns, y) -> tuple[float, np.ndarray]:
    X = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    return 1.0 - float(np.var(y - X @ coef)) / float(np.var(y)), coef


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bags", default="bags/disc_full/default_world")
    args = ap.parse_args(argv)
    if not (Path(args.bags) / "dataset.json").exists():
        exe = Path(sys.executable).with_name("soil_sim_batch")
        if subprocess.run([str(exe), *GRID, "--out", args.bags]).returncode != 0:  # soil_sim_batch said why
            sys.exit(f"bench_floor_reaction: could not generate the bags in {args.bags}")
    ds = load_dataset(args.bags)
    K = {n: i for i, n in enumerate(KNOWN_PARAMS)}
    T = {n: i for i, n in enumerate(GROUND_TRUTH_PARAMS)}
    O = {n: i for i, n in enumerate(OBSERVATION_FIELDS)}
    kn, ob, f, tr = ds.known, ds.observations, ds.forces, ds.truth
    _, fee_z, defined = fee_forces(tr[:, T["phi"]], tr[:, T["c"]], tr[:, T["delta"]], kn)
    d, vx, vz = kn[:, K["d"]], kn[:, K["v_x"]], kn[:, K["v_z"]]
    t = np.concatenate([np.arange(ds.offsets[e + 1] - ds.offsets[e]) / SAMPLE_RATE_HZ for e in range(len(ds.names))])
    m = (d > 0.01) & (t >= 1.0) & defined & np.isfinite(fee_z)
    rz = (f[:, 1] - fee_z)[m]
    lift_error = (ob[:, O["u_zr"]] - (ob[:, O["p_z_b"]] - ob[:, O["p_z_c"]]))[m]
    lift_rate = (ob[:, O["v_z_b"]] - ob[:, O["v_z_c"]])[m]
    cap = penetration_capacity(SimpleNamespace(phi=tr[:, T["phi"]], c=tr[:, T["c"]], gamma=kn[:, K["gamma"]], d=d,
                                               w=kn[:, K["w"]], blade_thickness=EDGE_WIDTH_M))
    capm, sink, one = cap[m], (vz < -VZ_GATE_M_S)[m], np.ones(int(m.sum()))
    speed = np.tanh(vx[m] / 0.3)
    pressed = lift_error < 0.0
    print(f"# The default world's F_z: {len(ds.names)} episodes, {int(m.sum())} analysed ticks\n")
    print(f"z residual of the FEE at the true soil: mean {rz.mean():.0f} N, std {rz.std():.0f} N "
          f"(measured F_z mean {f[m, 1].mean():.0f} N; FEE z mean {fee_z[m].mean():.0f} N)\n")
    print("| explanation of the z residual | R² | coefficients |")
    print("|---|---|---|")
    q, c = r2([lift_error, lift_rate, one], rz)
    print(f"| lift spring-damper: k_e (u_zr − z_rel) + k_v (v_z_b − v_z_c) + F_0 (the measurement itself) | {q:.3f} | "
          f"k_e {c[0] / 1e6:.2f} MN/m, k_v {c[1] / 1e3:.0f} kN·s/m, F_0 {c[2]:.0f} N |")
    q, c = r2([capm, capm * sink, capm * speed, one], rz)
    print(f"| soil state only: bearing capacity × (1, sinking, tanh(v_x/0.3)) + const | {q:.3f} | "
          f"{c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}, {c[3]:.0f} N |")
    q, c = r2([capm * pressed, capm * pressed * speed, capm * sink, one], rz)
    print(f"| with the gate 'lift commanded below the edge' | {q:.3f} | {c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}, {c[3]:.0f} N |")
    print("\nSteady (second half) F_z at 0.1 m against the bearing capacity at the true soil:\n")
    print("| episode | F_z [N] | capacity [N] | lift error [mm] |")
    print("|---|---|---|---|")
    err_all = ob[:, O["u_zr"]] - (ob[:, O["p_z_b"]] - ob[:, O["p_z_c"]])
    for e, name in enumerate(ds.names):
        r = ds.episode_rows(e)
        if abs(float(np.median(d[r])) - 0.1) > 0.01:
            continue
        s = slice(r.start + (r.stop - r.start) // 2, r.stop)
        print(f"| {name} | {f[s, 1].mean():.0f} | {cap[s].mean():.0f} | {1e3 * err_all[s].mean():.2f} |")


if __name__ == "__main__":
    main()
