"""Gross outliers (hykin.calibration.outliers): the threshold's margin on clean data, and what dropping
the outliers buys against keeping them (the peer, measured in the same run).

1. Clean data: the largest calibrated row error in units of the test's typical error ``s`` (the
   default threshold is 12 s) on virtual robots (3,000 poses each) and, when ``../shared/data`` is
   there, the public tracker sets ipa-robot-accuracy A/B and serial-robots-ur5.
2. Injected lost beams (``--bad`` rows moved ``--bad-mm``) in a virtual training set: calibrated
   error against the noise-free truth on held-out poses, ``--outliers keep`` vs ``drop``, and the
   rows found against the rows injected.

    python benchmarks/bench_outliers.py [--n 3000] [--bad 10] [--bad-mm 2,5]
"""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

import numpy as np

from hykin.calibration.calibrate import calibrate, calibrated_fk
from hykin.calibration.outliers import MAXWELL_MEDIAN, row_errors
from hykin.io.robot_file import load_robot
from hykin.sim.presets import virtual_preset
from hykin.sim.sampling import uniform
from hykin.sim.simulate import simulate


def simulate_preset(name: str, n: int, seed: int, noise: bool = True):
    """(dataset of ``n`` uniform poses, nominal robot) of virtual preset ``name``."""
    vr = virtual_preset(name)
    return simulate(vr, uniform(vr.nominal, n, seed), noise=noise, rng=seed), vr.nominal

SHARED = Path(os.environ.get("HYKIN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
VIRTUAL = ("rx160-virtual", "rx160-nongeo", "ur10-virtual", "kr-payload-virtual")


def tail_ratio(robot, ds) -> tuple[float, float | None]:
    """Largest calibrated row error / s (position, orientation) with outliers kept."""
    res = calibrate(robot, ds, outliers="keep", checks=False)
    T = calibrated_fk(res.robot, ds.q)
    R = ds.poses()[:, :3, :3] if ds.has_orientation else None
    e, a = row_errors(T, ds.xyz_m, R, None)
    r = lambda v: float(v.max() / (np.median(v) / MAXWELL_MEDIAN)) if np.median(v) > 1e-9 else float("nan")
    return r(e), None if a is None else r(a)


def clean_margins(n: int) -> None:
    print("| data | rows | max pos / s | max rot / s |\n|---|---|---|---|")
    cases = []
    for name in VIRTUAL:
        ds, nominal = simulate_preset(name, n, seed=3)
        cases.append((name, nominal, ds))
    if SHARED.is_dir():
        from hykin.measure.importers import import_ipa_series, import_ur5

        ipa = SHARED / "ipa-robot-accuracy"
        cases += [("ipa A", load_robot("ur10"), import_ipa_series(ipa / "Series_A")),
                  ("ipa B", load_robot("ur10"), import_ipa_series(ipa / "Series_B")),
                  ("ur5 grid", load_robot("ur5"), import_ur5(SHARED / "serial-robots-ur5" / "UR5" / "3D_UR5_uncalibrated_grid_cleaned.csv"))]
    for name, rob, ds in cases:
        p, a = tail_ratio(rob, ds)
        f = lambda v: "-" if v is None else "noise-free" if v != v else f"{v:.2f}"
        print(f"| {name} | {len(ds)} | {f(p)} | {f(a)} |", flush=True)


def injected(n: int, n_bad: int, sizes_mm: list[float]) -> None:
    ds, nominal = simulate_preset("ur10-virtual", n, seed=5)
    test, _ = simulate_preset("ur10-virtual", 1000, seed=6, noise=False)
    rng = np.random.default_rng(0)
    print("\n| lost beams | keep: held-out mm | drop: held-out mm | keep / drop | rows found / injected |\n|---|---|---|---|---|")
    for mm in sizes_mm:
        bad = np.sort(rng.choice(n, n_bad, replace=False))
        xyz = ds.xyz_m.copy()
        u = rng.standard_normal((n_bad, 3))
        xyz[bad] += mm * 1e-3 * u / np.linalg.norm(u, axis=1, keepdims=True)
        d = ds.subset(np.arange(n))
        d.xyz_m = xyz
        err = {}
        for mode in ("keep", "drop"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = calibrate(nominal, d, outliers=mode)
            err[mode] = float(np.linalg.norm(calibrated_fk(res.robot, test.q)[:, :3, 3] - test.xyz_m, axis=1).mean() * 1e3)
            if mode == "drop":
                found = set() if res.outliers is None else set(res.outliers.rows.tolist())
        hit = len(found & set(bad.tolist()))
        print(f"| {n_bad} x {mm:g} mm | {err['keep']:.4f} | {err['drop']:.4f} | {err['keep'] / err['drop']:.2f} | "
              f"{hit} of {n_bad} ({len(found) - hit} others) |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--bad", type=int, default=10)
    ap.add_argument("--bad-mm", default="1,2,5")
    a = ap.parse_args()
    clean_margins(a.n)
    injected(a.n, a.bad, [float(v) for v in a.bad_mm.split(",")])


if __name__ == "__main__":
    main()
