"""Real-data benchmark: the default hybrid pipeline on the two public laser-tracker data sets.

* UR5 (serial-robots-ur5, position only): train on the 1000-pose grid, test once on the 20 random
  poses: nominal / calibrated (geometry + compliance) / hybrid (default arch + recipe). Settings are
  chosen by k-fold cross-validation on the grid only (also printed); the test set is not tuned on.
* UR10 series A (ipa-robot-accuracy, registered to the nominal model): held-out 20 % split,
  full pose, nominal / calibrated / hybrid.
* UR10 series B in the tracker frame, registered to the series-A model (hykin.register) from 30
  poses vs from all poses: mean errors on all of B, ratio 30 / all (issue 6: <= 1.10).

Usage: python benchmarks/bench_real.py [--data ../shared/data] [--folds 5] [--seeds 0] [--no-cv]
Prints markdown tables. Skips a data set whose folder is absent.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hykin.geometry import se3
from hykin.hybrid.model import HybridModel, OutOfRangeWarning
from hykin.io.dataset import Dataset, split
from hykin.kinematics.fk import fk
from hykin.measure.importers import (
    import_ipa_series,
    import_ur5,
    ipa_nominal_robot,
    ur5_robot_for_dataset,
)
from hykin.measure.register import register_model


def pos_mm(T, ds):
    return np.linalg.norm(T[:, :3, 3] - ds.xyz_m, axis=1)


def subset(ds: Dataset, idx) -> Dataset:
    return Dataset(q=ds.q[idx], xyz_m=ds.xyz_m[idx], quat_wxyz=None if ds.quat_wxyz is None else ds.quat_wxyz[idx],
                   source=ds.source)


def ur5(root: Path, folds: int, seeds: list[int], cv: bool) -> None:
    d = root / "serial-robots-ur5" / "UR5"
    if not d.is_dir():
        print(f"(UR5 data not found under {d}: skipped)")
        return
    grid = import_ur5(d / "3D_UR5_uncalibrated_grid_cleaned.csv")
    test = import_ur5(d / "3D_UR5_uncalibrated_random_cleaned.csv")
    rob = ur5_robot_for_dataset()
    print("\n### UR5 (serial-robots-ur5): train grid (1000), test random (20), position error mm\n")
    if cv:
        perm = np.random.default_rng(123).permutation(len(grid))
        parts = np.array_split(perm, folds)
        cal, hyb = [], []
        t0 = time.perf_counter()
        for k in range(folds):
            tr = subset(grid, np.setdiff1d(perm, parts[k]))
            va = subset(grid, parts[k])
            m = HybridModel(rob, seed=0).fit(tr, progress=False)
            cal.append(pos_mm(m.predict_classical(va.q), va).mean())
            hyb.append(pos_mm(m.predict(va.q), va).mean())
        print(f"{folds}-fold cross-validation on the grid ({time.perf_counter() - t0:.0f} s): "
              f"calibrated {np.mean(cal) * 1e3:.4f} mm, hybrid {np.mean(hyb) * 1e3:.4f} mm "
              f"(folds: {' '.join(f'{h * 1e3:.4f}' for h in hyb)})\n")
    print("| model | mean mm | std mm | max mm | fit s |")
    print("|---|---|---|---|---|")
    e = pos_mm(fk(rob, test.q), test) * 1e3
    print(f"| nominal (published 2.566) | {e.mean():.4f} | {e.std():.4f} | {e.max():.4f} | - |")
    for s in seeds:
        t0 = time.perf_counter()
        m = HybridModel(rob, seed=s).fit(grid, progress=False)
        fs = time.perf_counter() - t0
        if s == seeds[0]:
            e = pos_mm(m.predict_classical(test.q), test) * 1e3
            print(f"| calibrated (geometry + compliance) | {e.mean():.4f} | {e.std():.4f} | {e.max():.4f} | - |")
        e = pos_mm(m.predict(test.q), test) * 1e3
        print(f"| hybrid default, seed {s} (published 0.155) | {e.mean():.4f} | {e.std():.4f} | {e.max():.4f} | {fs:.0f} |")


def ur10(root: Path) -> None:
    d = root / "ipa-robot-accuracy"
    if not (d / "Series_A").is_dir():
        print(f"(UR10 data not found under {d}: skipped)")
        return
    rob = ipa_nominal_robot()
    A = import_ipa_series(d / "Series_A", register_to=rob)
    tr, te = split(A, (0.8, 0.2), seed=0)
    t0 = time.perf_counter()
    m = HybridModel(rob, seed=0).fit(tr, progress=False)
    fs = time.perf_counter() - t0
    print(f"\n### UR10 series A (registered to the nominal model): train {len(tr)}, test {len(te)} (held-out 20 %)\n")
    print("| model | pos mean mm | pos p95 mm | ang mean deg | ang p95 deg |")
    print("|---|---|---|---|---|")
    for name, T in (("nominal (rigid fit)", fk(rob, te.q)), ("calibrated", m.predict_classical(te.q)),
                    (f"hybrid default (fit {fs:.0f} s)", m.predict(te.q))):
        p, a = se3.pose_error(te.poses(), T)
        print(f"| {name} | {p.mean():.4f} | {np.percentile(p, 95):.4f} | {a.mean():.4f} | {np.percentile(a, 95):.4f} |")
    if not (d / "Series_B").is_dir():
        return
    B = import_ipa_series(d / "Series_B")  # tracker frame
    print(f"\n### UR10 series B (tracker frame, {len(B)} poses) registered to the series-A model\n")
    print("| poses used | pos mean mm (all B) | ang mean deg (all B) | pos ratio vs all | s |")
    print("|---|---|---|---|---|")
    res = {}
    for n in (len(B), 10, 20, 30):
        t0 = time.perf_counter()
        m2, info = register_model(m, B, n_poses=n)
        p, a = se3.pose_error(B.poses(), m2.predict(B.q))
        res[n] = p.mean()
        print(f"| {n} | {p.mean():.4f} | {a.mean():.4f} | {p.mean() / res[len(B)]:.3f} | {time.perf_counter() - t0:.1f} |")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r30 = [se3.pose_error(B.poses(), register_model(m, B, n_poses=30, seed=s)[0].predict(B.q))[0].mean()
               for s in range(1, 5)]
    print(f"\n30-pose ratio over k-means seeds 1-4: {' '.join(f'{x / res[len(B)]:.3f}' for x in r30)}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--no-cv", action="store_true")
    ap.add_argument("--skip", nargs="*", default=[], choices=["ur5", "ur10"])
    args = ap.parse_args()
    warnings.simplefilter("ignore", OutOfRangeWarning)
    root = Path(args.data)
    if "ur5" not in args.skip:
        ur5(root, args.folds, args.seeds, not args.no_cv)
    if "ur10" not in args.skip:
        ur10(root)


if __name__ == "__main__":
    main()
