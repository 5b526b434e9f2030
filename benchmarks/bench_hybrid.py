"""Hybrid model benchmark: accuracy vs training-set size, training time, predict speed.

Virtual robots from hykin.simulate (rx160-virtual, rx160-nongeo). Training data: uniform joint
samples with the preset's measurement noise; test set: 5000 random joints, noise-free truth
(so the figures are model error, not tracker noise). rx160-nongeo has thermal drift over the sample
index, which no function of q can learn: its rows also give the error at the training set's mean
temperature. Rows: nominal model, calibrated classical
model, hybrid (default arch + recipe) at each size, and the paper recipe with D4w (time-boxed) as
the peer measured in the same run. Speed: hybrid predict vs classical FK, same batch.

Usage: python benchmarks/bench_hybrid.py [--sizes 1000 10000] [--presets rx160-virtual rx160-nongeo]
       [--paper-seconds 300] [--no-paper] [--threads 2]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hykin.geometry import se3
from hykin.hybrid.model import HybridModel, OutOfRangeWarning, classical_fk
from hykin.kinematics.fk import fk
from hykin.sim.presets import virtual_preset
from hykin.sim.simulate import simulate


def errors(T_pred, ds):
    pos, ang = se3.pose_error(ds.poses(), T_pred)
    return float(pos.mean()), float(ang.mean())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--presets", nargs="+", default=["rx160-virtual", "rx160-nongeo"])
    ap.add_argument("--paper-seconds", type=float, default=300.0, help="time box per net for the paper recipe")
    ap.add_argument("--paper-size", type=int, default=10000)
    ap.add_argument("--no-paper", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--arch", default="default")
    ap.add_argument("--epochs", type=int, default=None, help="override max_epochs of the default recipe")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore", OutOfRangeWarning)
    rows = []
    for preset in args.presets:
        vr = virtual_preset(preset)
        rng = np.random.default_rng(7)
        q_test = vr.nominal.random_joints(5000, rng, margin=0.02)
        test = simulate(vr, q_test, noise=False)
        nom = errors(fk(vr.nominal, q_test) if not vr.nominal.has_compliance else classical_fk(vr.nominal, q_test), test)
        rows.append((preset, "nominal", "-", 0, *nom, 0.0))
        runs = [(n, args.arch, "default", None) for n in args.sizes]
        if not args.no_paper:
            runs.append((args.paper_size, "D4w", "paper", args.paper_seconds))
        for n, arch, recipe, ms in runs:
            q_train = vr.nominal.random_joints(n, np.random.default_rng(100 + n))
            train = simulate(vr, q_train, noise=True, rng=1)
            kw = {"max_epochs": args.epochs} if (args.epochs and recipe == "default") else None
            m = HybridModel(vr.nominal, arch=arch, recipe=recipe, seed=0, max_seconds=ms, recipe_kw=kw)
            t0 = time.perf_counter()
            m.fit(train, progress=False)
            fit_s = time.perf_counter() - t0
            cal = errors(m.predict_classical(q_test), test)
            hyb = errors(m.predict(q_test), test)
            if "temperature_c" in train.extra:  # thermal drift is not a function of q: also test at the
                # training set's mean temperature, which isolates what the networks can learn
                t_mean = float(np.mean(train.extra["temperature_c"]))
                test_t = simulate(vr, q_test, noise=False, temperature=np.full(len(q_test), t_mean))
                cal_t, hyb_t = errors(m.predict_classical(q_test), test_t), errors(m.predict(q_test), test_t)
                print(f"    at training mean temperature {t_mean:.2f} C: calibrated {cal_t[0]:.3g} mm "
                      f"{cal_t[1]:.3g} deg, hybrid {hyb_t[0]:.3g} mm {hyb_t[1]:.3g} deg", flush=True)
            if n == args.sizes[0] and recipe == "default":
                rows.append((preset, "calibrated", "-", n, *cal, m.meta_["timings"]["calibrate_s"]))
            rows.append((preset, f"hybrid {arch}/{recipe}", m.meta_["train_results"]["pos"]["stopped"], n, *hyb, fit_s))
            print(f"  {preset} {arch}/{recipe} n={n}: calibrated {cal[0]:.3g} mm {cal[1]:.3g} deg, hybrid "
                  f"{hyb[0]:.3g} mm {hyb[1]:.3g} deg, fit {fit_s:.1f} s (calibrate "
                  f"{m.meta_['timings']['calibrate_s']:.1f} s, epochs pos "
                  f"{m.meta_['train_results']['pos']['epochs']})", flush=True)
            if recipe == "default" and n == max(args.sizes):
                last = m
    print(f"\n{'preset':15s} {'model':26s} {'stop':14s} {'n_train':>8s} {'pos mm':>10s} {'rot deg':>10s} {'time s':>8s}")
    for r in rows:
        print(f"{r[0]:15s} {r[1]:26s} {r[2]:14s} {r[3]:8d} {r[4]:10.3g} {r[5]:10.3g} {r[6]:8.1f}")
    # speed: hybrid predict vs classical FK (peer), same batch
    q = last.robot.random_joints(200_000, 3)
    last.predict(q[:1000])
    classical_fk(last.robot_, q[:1000])
    best_h, best_c = np.inf, np.inf
    for _ in range(3):
        t0 = time.perf_counter(); last.predict(q); best_h = min(best_h, time.perf_counter() - t0)
        t0 = time.perf_counter(); classical_fk(last.robot_, q); best_c = min(best_c, time.perf_counter() - t0)
    print(f"\npredict speed (batch {len(q)}, {args.threads} threads): hybrid {len(q) / best_h:,.0f} poses/s, "
          f"calibrated classical (compliant FK) {len(q) / best_c:,.0f} poses/s, ratio hybrid/classical "
          f"{best_c / best_h:.2f}")


if __name__ == "__main__":
    main()
