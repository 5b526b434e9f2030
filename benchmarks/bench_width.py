"""Narrower residual networks against the default: held-out accuracy and hybrid FK batch speed (#25).

Why the default networks stay 3 x 64: #25 asks hybrid FK batches to reach 0.8x the calibrated classical
model's throughput, which the default's multiply-adds cannot at this machine's matrix-product peak
(``bench_compensator.py`` measures that bound). This script measures what narrower networks would cost
in accuracy and gain in speed, on real data and on two virtual robots:

* UR10 series A (ipa-robot-accuracy, registered to the nominal model), 80/20 split, held-out error
  against the measurements;
* rx160-nongeo and ur10-virtual presets, 5,000 noisy training poses, 3,000 test poses against the
  noise-free truth.

Widths: the default (3 x 64 SiLU, trig features) and two narrower ones registered here (3 x 32, 2 x 32;
not hykin architectures). Same recipe and seed for all. FK ratio: median of 5 calls of ``predict`` and
``predict_classical`` on 100,000 random joints.

    python benchmarks/bench_width.py [--data ../shared/data] [--n-train 5000]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hykin.geometry import se3  # noqa: E402
from hykin.hybrid import nets  # noqa: E402
from hykin.hybrid.model import HybridModel  # noqa: E402
from hykin.io.dataset import split  # noqa: E402
from hykin.measure.importers import import_ipa_series, ipa_nominal_robot  # noqa: E402
from hykin.sim.presets import virtual_preset  # noqa: E402
from hykin.sim.simulate import simulate  # noqa: E402

WIDTHS = {"default": None, "3x32": [32, 32, 32], "2x32": [32, 32]}


def median_s(fn, reps: int = 5) -> float:
    fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def datasets(root: Path, n_train: int):
    d = root / "ipa-robot-accuracy" / "Series_A"
    if d.is_dir():
        rob = ipa_nominal_robot()
        tr, te = split(import_ipa_series(d, register_to=rob), (0.8, 0.2), seed=0)
        yield "UR10 series A (real)", rob, tr, te
    else:
        print(f"(UR10 data not found under {d}: skipped)")
    for preset in ("rx160-nongeo", "ur10-virtual"):
        vr = virtual_preset(preset)
        q_tr, q_te = vr.nominal.random_joints(n_train, 11), vr.nominal.random_joints(3000, 12)
        yield preset, vr.nominal, simulate(vr, q_tr, noise=True, rng=1), simulate(vr, q_te, noise=False)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--n-train", type=int, default=5000)
    a = ap.parse_args()
    for name, w in WIDTHS.items():
        if w is not None:
            nets.ARCHITECTURES[name] = dict(kind="mlp", widths=w, act="silu", features="trig", ref="bench_width.py")
    print("| data | width | pos mean mm | pos p95 mm | pos max mm | ang mean deg | fit s | FK ratio at 100,000 |")
    print("|---|---|---|---|---|---|---|---|")
    warnings.simplefilter("ignore")
    for label, rob, tr, te in datasets(Path(a.data), a.n_train):
        for arch in WIDTHS:
            t0 = time.perf_counter()
            m = HybridModel(rob, arch=arch, seed=0).fit(tr, progress=False)
            fit_s = time.perf_counter() - t0
            p, ang = se3.pose_error(te.poses(), m.predict(te.q))
            q = m.robot.random_joints(100_000, 3)
            ratio = median_s(lambda: m.predict_classical(q)) / median_s(lambda: m.predict(q))
            print(f"| {label} | {arch} | {p.mean():.4f} | {np.percentile(p, 95):.4f} | {p.max():.4f} | "
                  f"{ang.mean():.5f} | {fit_s:.0f} | {ratio:.2f} |", flush=True)


if __name__ == "__main__":
    main()
