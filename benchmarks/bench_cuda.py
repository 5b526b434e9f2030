"""Training on a GPU: ``hykin fit --device cuda`` against ``--device cpu`` on the same data (issue #18).

Simulates ``-n`` training rows (default 100,000) and 5,000 test rows of ``rx160-virtual``, then runs
the command line twice with the same data, options and seed, once per device::

    hykin fit rx160 train.csv -o cpu.hykin --device cpu  --min-steps S --seed 0
    hykin fit rx160 train.csv -o gpu.hykin --device cuda --min-steps S --seed 0

and reports the wall time of each ``fit`` (ratio cuda / cpu), the test error of both models and how
far their predictions lie apart. The two are not bit-identical (other kernels, other reduction
orders); they must agree to a small fraction of the model's own error. Without a CUDA device the
script prints a line saying so and exits 0 (CI never has one).

    python benchmarks/bench_cuda.py [-n 100000] [--min-steps 30000] [--cpu-threads K] [--concurrent]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _env(threads: int | None) -> dict:
    env = dict(os.environ)
    if threads:
        env.update(OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    return env


def hykin(*args: str, threads: int | None = None) -> float:
    """Run ``python -m hykin ARGS``; returns its wall time in seconds (raises on failure)."""
    return hykin_all([args], threads=[threads])[0]


def hykin_all(commands: list, threads: list) -> list[float]:
    """Run several ``python -m hykin ...`` commands at once; returns each one's wall time (s)."""
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-m", "hykin", *a], env=_env(t), stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for a, t in zip(commands, threads)]
    times = [0.0] * len(procs)
    pending = set(range(len(procs)))
    while pending:
        for i in list(pending):
            if procs[i].poll() is not None:
                times[i] = time.perf_counter() - t0
                pending.discard(i)
        time.sleep(0.05)
    for a, p in zip(commands, procs):
        if p.returncode != 0:
            raise SystemExit(f"hykin {' '.join(a)} failed:\n{p.stderr.read()[-2000:]}")
    return times


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=100_000)
    ap.add_argument("--preset", default="rx160-nongeo", help="virtual robot (its robot file: the preset's base name)")
    ap.add_argument("--max-epochs", type=int, default=None, help="epochs per network (default: the recipe's)")
    ap.add_argument("--min-steps", type=int, default=None, help="steps per network (default: the recipe's)")
    ap.add_argument("--cpu-threads", type=int, default=None)
    ap.add_argument("--concurrent", action="store_true", help="run the two fits at the same time")
    ap.add_argument("--keep", default=None, help="folder to keep the data and models in")
    args = ap.parse_args(argv)

    import torch

    if not torch.cuda.is_available():
        print("skipped: no CUDA device on this machine (torch.cuda.is_available() is False)")
        return 0

    from hykin.geometry.se3 import pose_error
    from hykin.hybrid.model import HybridModel
    from hykin.io.dataset_files import read_dataset

    work = Path(args.keep or tempfile.mkdtemp(prefix="hykin-cuda-"))
    work.mkdir(parents=True, exist_ok=True)
    # One simulated robot (the truth depends on the seed): N + 5,000 rows, split off 5,000 for testing.
    data, train, test = work / "data.csv", work / "data_train.csv", work / "data_test.csv"
    hykin("simulate", args.preset, "-n", str(args.n + 5000), "-o", str(data), "--seed", "0", "--force")
    hykin("split", str(data), "-o", str(work / "data"), "--test", str(5000 / (args.n + 5000)), "--force")
    steps = ["--min-steps", str(args.min_steps)] if args.min_steps else []
    steps += ["--max-epochs", str(args.max_epochs)] if args.max_epochs else []
    robot = args.preset.split("-")[0]
    fits = {dev: ("fit", robot, str(train), "-o", str(work / f"{dev}.hykin"), "--device", dev,
                  "--seed", "0", "--force", *steps) for dev in ("cpu", "cuda")}
    threads = {"cpu": args.cpu_threads, "cuda": None}
    if args.concurrent:  # both at once: the GPU run needs one core, the CPU run gets the rest
        times = dict(zip(fits, hykin_all(list(fits.values()), [threads[d] for d in fits])))
    else:
        times = {dev: hykin(*cmd, threads=threads[dev]) for dev, cmd in fits.items()}
    te = read_dataset(test)
    models = {dev: HybridModel.load(work / f"{dev}.hykin") for dev in times}
    kw = {"temperature_c": te.extra["temperature_c"]} if "temperature_c" in te.extra else {}
    pred = {dev: m.predict(te.q, **kw) for dev, m in models.items()}
    net_p, _ = pose_error(pred["cpu"], models["cpu"].predict_classical(te.q, **kw))
    err = {dev: pose_error(T, te.poses()) for dev, T in pred.items()}
    dp, da = pose_error(pred["cuda"], pred["cpu"])
    gpu = torch.cuda.get_device_name(0)

    print(f"{args.preset}, {len(read_dataset(train)):,} training rows, {len(te):,} test rows; steps per network: "
          f"{args.min_steps or 'recipe default'}; epochs: {args.max_epochs or 'recipe default'}; CUDA device: {gpu}; CPU: {os.cpu_count()} cores"
          f"{f', {args.cpu_threads} threads' if args.cpu_threads else ''}"
          f"{'; the two fits ran at the same time' if args.concurrent else ''}\n")
    print("| device | fit wall time | test position error (mean) | test orientation error (mean) |")
    print("|---|---|---|---|")
    for dev in times:
        p, a = err[dev]
        print(f"| {dev} | {times[dev]:.0f} s | {p.mean():.4f} mm | {a.mean():.4f}° |")
    print(f"\nfit time cuda / cpu: **{times['cuda'] / times['cpu']:.2f}**")
    print(f"test error cuda / cpu: position {err['cuda'][0].mean() / err['cpu'][0].mean():.3f}, "
          f"orientation {err['cuda'][1].mean() / err['cpu'][1].mean():.3f}")
    print(f"size of the networks' correction (cpu model, hybrid - calibrated): mean {net_p.mean() * 1e3:.2f} µm")
    print(f"cuda vs cpu predictions on the test joints: mean {dp.mean() * 1e3:.3f} µm, max {dp.max() * 1e3:.3f} µm; "
          f"mean {da.mean() * 3600:.4f}\", max {da.max() * 3600:.4f}\"")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
