"""The same sweep trials on the GPU and on the CPU, without Ray: time and agreement.

    python benchmarks/sweep_device.py [--trials 4] [--n 20000] [--epochs 30] [--devices cpu,cuda]
    python benchmarks/sweep_device.py --sweep examples/sweeps/paper-table1.toml --devices cpu,cuda
    python benchmarks/sweep_device.py --ray [--trials 4] [--n 20000] [--epochs 20] [--wide 2] [--dir DIR]

Each trial is :func:`hykin.distributed.trials.run_trial` (what a `hykin sweep` trial runs in its Ray
worker) with ``device`` set to each of ``--devices`` in turn, one torch/numba thread per trial on the
CPU. Default trials: the seeds ``0..trials-1`` of hykin's default fit (calibration + default nets,
``--epochs`` epochs, no step floor) on ``--n`` noise-free rx160-virtual samples, tested on 2,000.
With ``--sweep FILE`` the trials and datasets of that sweep file instead. A device that torch does not
have (cuda without a GPU) is skipped with a printed line. Needs no Ray.

With ``--ray``: the same trials through the CLI, ``hykin sweep`` on a local Ray, twice -- once with
``cpus_per_trial = 1, gpus_per_trial = 0`` and once with ``gpus_per_trial = --gpu-share`` (the trials
name no device, so the GPU sweep's fits run on "cuda") -- plus ``--wide`` seeds of the paper's D4w
network (networks alone, the paper recipe, 4 epochs on 5,000 rows), where a GPU pays. Prints each
sweep's wall time and both results.csv side by side.

Prints a markdown table per trial (fit s per device, hybrid test error per device) and the largest
difference of the hybrid error between the first device and each other one (mm, and relative).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path


def sweep_files(n_train: int, n_test: int, trials: int, epochs: int, d: Path) -> Path:
    """Write rx160-virtual train/test sets (noise-free; seeds 0 / 1) and a sweep file over ``trials``
    seeds of the default fit with ``epochs`` epochs into ``d``; returns the sweep file."""
    from hykin.io.dataset_files import write_dataset
    from hykin.io.robot_file import load_robot
    from hykin.sim.presets import virtual_preset
    from hykin.sim.simulate import simulate

    vr, rob = virtual_preset("rx160-virtual", seed=0), load_robot("rx160")
    for name, n, seed in (("train.csv", n_train, 0), ("test.csv", n_test, 1)):
        write_dataset(simulate(vr, rob.random_joints(n, seed, margin=0.05), noise=False, rng=seed), d / name)
    path = d / "s.toml"
    path.write_text(f'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n[grid]\nseed = {list(range(trials))}\n'
                    f"max_epochs = [{epochs}]\nmin_steps = [0]\n[resources]\ncpus_per_trial = 1\n", encoding="utf-8")
    return path


def ray_sweeps(a) -> None:
    """``hykin sweep`` on a local Ray, CPU trials then GPU trials (module docstring)."""
    import csv
    import subprocess
    import sys

    d = Path(a.dir or tempfile.mkdtemp())
    d.mkdir(parents=True, exist_ok=True)
    base = sweep_files(a.n, 2000, a.trials, a.epochs, d).read_text(encoding="utf-8").split("[resources]")[0]
    grids = base.replace("[grid]", "[[grid]]")
    if a.wide:
        grids += (f'[[grid]]\narch = ["D4w"]\nrecipe = ["paper"]\ncalibrate = [false]\nmax_epochs = [4]\nmin_steps = [0]\n'
                  f"n_train = [{min(5000, a.n)}]\nseed = {list(range(a.wide))}\n")
    walls, rows = {}, {}
    for name, res in (("cpu", "cpus_per_trial = 1\ngpus_per_trial = 0\n"),
                      ("cuda", f"cpus_per_trial = 1\ngpus_per_trial = {a.gpu_share}\n")):
        f = d / f"sweep-{name}.toml"
        f.write_text(grids + "[resources]\n" + res, encoding="utf-8")
        out = d / f"out-{name}"
        cmd = [sys.executable, "-m", "hykin", "sweep", str(f), "-o", str(out)]
        print("$", " ".join(cmd), flush=True)
        t0 = time.perf_counter()
        rc = subprocess.run(cmd).returncode
        walls[name] = time.perf_counter() - t0
        print(f"{name}: rc {rc}, {walls[name]:.1f} s wall", flush=True)
        if rc:
            raise SystemExit(f"hykin sweep {f} failed (rc {rc})")
        with open(out / "results.csv", newline="", encoding="utf-8") as fh:
            rows[name] = [r for r in csv.DictReader(fh) if not r.get("trial", "").startswith("#")]
    print("| trial | arch | seed | status cpu/cuda | fit s cpu | fit s cuda | hybrid mm cpu | hybrid mm cuda | |diff| mm |")
    print("|---|---|---|---|---|---|---|---|---|")
    worst = 0.0
    for x, y in zip(rows["cpu"], rows["cuda"]):
        hx, hy = float(x["hybrid_pos_mean_mm"] or "nan"), float(y["hybrid_pos_mean_mm"] or "nan")
        worst = max(worst, abs(hx - hy))
        print(f"| {x['trial']} | {x.get('arch') or 'default'} | {x['seed']} | {x['status']}/{y['status']} | "
              f"{float(x['fit_s'] or 'nan'):.1f} | {float(y['fit_s'] or 'nan'):.1f} | {hx:.6f} | {hy:.6f} | {abs(hx - hy):.2e} |")
    print(f"sweep wall: cpu {walls['cpu']:.1f} s, cuda {walls['cuda']:.1f} s; hybrid errors differ by at most {worst:.2e} mm")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=4)
    ap.add_argument("--n", type=int, default=20000)
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--devices", default="cpu,cuda")
    ap.add_argument("--sweep", type=Path, default=None, help="a sweep file: its trials and datasets")
    ap.add_argument("--ray", action="store_true", help="run `hykin sweep` on a local Ray, CPU then GPU trials")
    ap.add_argument("--wide", type=int, default=2, help="--ray: seeds of the paper's D4w trials added")
    ap.add_argument("--gpu-share", type=float, default=0.5, help="--ray: gpus_per_trial of the GPU sweep")
    ap.add_argument("--dir", default=None, help="--ray: where the data, sweep files and results go")
    a = ap.parse_args()
    if a.ray:
        return ray_sweeps(a)
    import torch

    from hykin.distributed.sweep_file import read_sweep
    from hykin.distributed.trials import run_trial
    from hykin.io.dataset_files import read_dataset
    from hykin.io.robot_file import load_robot

    path = a.sweep or sweep_files(a.n, 2000, a.trials, a.epochs, Path(tempfile.mkdtemp()))
    spec = read_sweep(path)
    rob = load_robot(spec.robot)
    train, test = read_dataset(spec.train, robot=rob), read_dataset(spec.test, robot=rob)
    devices = []
    for dev in a.devices.split(","):
        if dev.startswith("cuda") and not torch.cuda.is_available():
            print(f"{dev}: skipped (torch.cuda.is_available() is False)")
        else:
            devices.append(dev)
    trials = spec.trials()
    print(f"{len(trials)} trials, {len(train)} training / {len(test)} test samples; torch {torch.__version__}; "
          f"devices {', '.join(devices)}" + (f" ({torch.cuda.get_device_name(0)})" if any(
              d.startswith("cuda") for d in devices) else ""))
    res = {}
    for dev in devices:
        t0 = time.perf_counter()
        res[dev] = [run_trial(rob, train, test, {**t, "device": dev}, spec.subsample_seed,
                              threads=max(1, round(spec.cpus_per_trial)) if dev == "cpu" else None) for t in trials]
        print(f"{dev}: {time.perf_counter() - t0:.1f} s for {len(trials)} trials")
    print("| trial | options | " + " | ".join(f"fit s {d}" for d in devices) + " | "
          + " | ".join(f"hybrid mm {d}" for d in devices) + " |")
    print("|---|---|" + "---|" * (2 * len(devices)))
    for i, t in enumerate(trials):
        opts = " ".join(f"{k}={v}" for k, v in t.items())
        print(f"| {i} | {opts} | " + " | ".join(f"{res[d][i]['fit_s']:.1f}" for d in devices) + " | "
              + " | ".join(f"{res[d][i]['hybrid_pos_mean_mm']:.5f}" for d in devices) + " |")
    ref = devices[0]
    for d in devices[1:]:
        diff = [abs(x["hybrid_pos_mean_mm"] - y["hybrid_pos_mean_mm"]) for x, y in zip(res[ref], res[d])]
        rel = [df / max(abs(x["hybrid_pos_mean_mm"]), 1e-12) for df, x in zip(diff, res[ref])]
        speed = sum(x["fit_s"] for x in res[ref]) / sum(y["fit_s"] for y in res[d])
        print(f"{d} vs {ref}: fit time ratio {speed:.2f}x ({ref} / {d}); hybrid error differs by at most "
              f"{max(diff):.2e} mm ({max(rel):.1%} relative); calibrated parts identical: "
              f"{all(x['calibrated_pos_mean_mm'] == y['calibrated_pos_mean_mm'] for x, y in zip(res[ref], res[d]))}")


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    main()
