"""Benchmark: simulating virtual-robot datasets (hykin.simulate), 500k samples target <= 30 s on 2 cores.

Prints a table: stage, samples, seconds, samples/s, ratio vs plain rigid FK of the same joints (the
peer measured in the same run: hykin.fk numba kernel). Usage::

    python benchmarks/bench_simulate.py [-n 500000] [--preset rx160-nongeo] [--no-write] [--csv]

``simulate_to_file`` is timed with Parquet output by default; ``--csv`` adds CSV output (dominated
by CSV text formatting in hykin.io.dataset_files.write_dataset, not by the simulation).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import best_of

from hykin.kinematics.compliance import deflected_joints, gravity_torques
from hykin.kinematics.fk import fk
from hykin.sim.generate import simulate_to_file
from hykin.sim.presets import virtual_preset
from hykin.sim.sampling import sample
from hykin.sim.simulate import simulate


def timed(fn, repeat: int = 1):
    return best_of(fn, repeat)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-n", type=int, default=500_000)
    ap.add_argument("--preset", default="rx160-nongeo")
    ap.add_argument("--no-write", action="store_true", help="skip simulate_to_file")
    ap.add_argument("--csv", action="store_true", help="also time simulate_to_file with CSV output")
    args = ap.parse_args()
    n = args.n
    vr = virtual_preset(args.preset)
    # warm up numba kernels
    q_small = sample("uniform", vr.nominal, 64, 0)
    simulate(vr, q_small)
    fk(vr.truth, q_small)

    rows = []
    t_plan, q = timed(lambda: sample("uniform", vr.nominal, n, 0))
    rows.append(("plan uniform (Sobol)", t_plan))
    t_zz, _ = timed(lambda: sample("zigzag", vr.nominal, n, 0))
    rows.append(("plan zigzag", t_zz))
    t_fk, _ = timed(lambda: fk(vr.truth, q), repeat=3)
    rows.append(("peer: rigid fk (numba)", t_fk))
    t_tau, _ = timed(lambda: gravity_torques(vr.truth, q), repeat=2)
    rows.append(("gravity_torques", t_tau))
    t_def, _ = timed(lambda: deflected_joints(vr.truth, q), repeat=2)
    rows.append(("deflected_joints", t_def))
    t_sim, _ = timed(lambda: simulate(vr, q, noise=True, rng=1))
    rows.append((f"simulate ({args.preset}, noise)", t_sim))
    if not args.no_write:
        with tempfile.TemporaryDirectory() as d:
            for ext in ("parquet", "csv") if args.csv else ("parquet",):
                t, _ = timed(lambda: simulate_to_file(args.preset, n, Path(d) / f"data.{ext}", seed=0))
                rows.append((f"simulate_to_file .{ext}", t))

    print(f"Simulation of {n} samples, preset {args.preset} (target: 500k in <= 30 s on 2 cores)\n")
    print("| stage | samples | seconds | samples/s | time vs rigid fk |")
    print("|---|---:|---:|---:|---:|")
    for name, t in rows:
        print(f"| {name} | {n} | {t:.3f} | {n / t:.3g} | {t / t_fk:.1f} |")


if __name__ == "__main__":
    main()
