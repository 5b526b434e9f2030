"""A sweep on a local Ray against the same trials one after another in one process.

    python benchmarks/bench_sweep.py [--trials 4] [--cpus 2] [--n 600] [--epochs 20]

Prints the wall time of both, Ray's start, their ratio, and Ray's overhead per trial: (sweep wall x
CPUs - sum of the trials' own fit times) / trials, which includes worker start-up (Python + torch
import; workers are reused), the object store and Tune's bookkeeping (and any idle CPU at the end).
Needs the `distributed` extra.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=4)
    ap.add_argument("--cpus", type=int, default=2)
    ap.add_argument("--n", type=int, default=600)
    ap.add_argument("--epochs", type=int, default=20)
    a = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from hykin.distributed.sweep import run_sweep
    from hykin.distributed.sweep_file import read_sweep
    from hykin.distributed.trials import run_trial
    from hykin.io.dataset_files import read_dataset, write_dataset
    from hykin.io.robot_file import load_robot
    from hykin.sim.presets import virtual_preset
    from hykin.sim.simulate import simulate

    d = Path(tempfile.mkdtemp())
    vr = virtual_preset("rx160-virtual", seed=0)
    rob = load_robot("rx160")
    for name, n, seed in (("train.csv", a.n, 0), ("test.csv", 300, 1)):
        write_dataset(simulate(vr, rob.random_joints(n, seed, margin=0.05), noise=False, rng=seed), d / name)
    seeds = list(range(a.trials))
    (d / "s.toml").write_text(f'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n[grid]\nseed = {seeds}\n'
                              f"max_epochs = [{a.epochs}]\nmin_steps = [0]\n", encoding="utf-8")
    spec = read_sweep(d / "s.toml")
    train, test = read_dataset(d / "train.csv", robot=rob), read_dataset(d / "test.csv", robot=rob)
    t0 = time.perf_counter()
    serial = [run_trial(rob, train, test, t) for t in spec.trials()]
    t_serial = time.perf_counter() - t0
    import ray

    t0 = time.perf_counter()
    ray.init(num_cpus=a.cpus, include_dashboard=False, logging_level="warning")
    t_init = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = run_sweep(spec, d / "out", log=lambda s: None)  # in the session started above
    t_sweep = time.perf_counter() - t0
    ray.shutdown()
    own = sum(r["fit_s"] for r in res.rows)  # fit only; evaluation is small here
    same = all(np.isclose(r["hybrid_pos_mean_mm"], s["hybrid_pos_mean_mm"], rtol=0, atol=0)
               for r, s in zip(res.rows, serial))
    print(f"| trials | n_train | epochs | serial s | Ray start s | sweep s ({a.cpus} CPUs) | speed-up (with start) | "
          "overhead per trial s | same errors |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(f"| {a.trials} | {a.n} | {a.epochs} | {t_serial:.1f} | {t_init:.1f} | {t_sweep:.1f} | {t_serial / t_sweep:.2f}x "
          f"({t_serial / (t_sweep + t_init):.2f}x) | {(t_sweep * a.cpus - own) / a.trials:.1f} | {same} |")


if __name__ == "__main__":
    main()
