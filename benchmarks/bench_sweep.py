"""A sweep on a local Ray against the same trials one after another in one process, and where Ray's
overhead goes.

    python benchmarks/bench_sweep.py [--trials 8] [--cpus 2] [--n 1000] [--epochs 60]

Both runs use the same per-trial settings: one torch/numba thread per CPU of a trial (1 here:
``hykin.distributed.trials.run_trial(..., threads=1)``), the same datasets and seeds. The serial run
is in this process after one import of torch + hykin (timed apart); the sweep is
``hykin.distributed.sweep.run_sweep`` in a local Ray with ``--cpus`` CPUs started just before (timed
apart: "Ray start").

Prints one table row (wall times, speed-up with and without Ray's start, and counting the serial
process's one torch + hykin import as the sweep's workers' imports are counted; overhead per trial) and the
decomposition of the overhead per trial, in CPU-slot seconds (``sweep wall x CPUs`` = the trials'
own work + what follows), from the times each trial records (``timing`` of the sweep's rows):

* set-up: from the call to the first trial sent to a worker (x CPUs); end: last trial recorded ->
  return, incl. the actors' end, results.csv and the plot (x CPUs);
* worker start / dispatch: trial sent -> it began in its worker, less the import and transfer below
  (a fresh worker process's start for a worker's first trial; the call's round trip after that);
* import: torch + hykin's fit path in a fresh worker (once per worker);
* transfer: the datasets from the object store (once per worker);
* report: the trial ended in its worker -> the driver recorded its row (results.csv rewritten);
* idle: CPU slots with no trial (the tail when trials do not divide evenly, waits);
* contention: (trials' run time in the sweep - in the serial run) -- on an idle machine close to 0;
  on a shared one the cores' other users slow the parallel trials more.

Also the CPU seconds used by the driver (Tune's loop), the trial workers beyond their trials, and
Ray's other processes (gcs, raylet, agents, idle workers) during the sweep, read from /proc (Linux).
Needs the `distributed` extra.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.procs import descendants, proc_table  # noqa: E402


def _cpu_s() -> dict:
    """pid -> CPU seconds of this process and its descendants (Ray's processes when it started them)."""
    table = proc_table()
    return {p: table[p][2] for p in [os.getpid(), *descendants(os.getpid(), table)] if p in table}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=8)
    ap.add_argument("--cpus", type=int, default=2)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--epochs", type=int, default=60)
    a = ap.parse_args()
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(k, "1")
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    import torch  # noqa: F401 - the serial run's one import, timed apart

    from hykin.distributed.sweep import run_sweep
    from hykin.distributed.sweep_file import read_sweep
    from hykin.distributed.trials import run_trial
    from hykin.evaluation import evaluate  # noqa: F401
    from hykin.hybrid import model  # noqa: F401
    from hykin.io.dataset_files import read_dataset
    from hykin.io.robot_file import load_robot
    from sweep_device import sweep_files

    t_import = time.perf_counter() - t0
    d = Path(tempfile.mkdtemp())
    spec = read_sweep(sweep_files(a.n, 300, a.trials, a.epochs, d))
    rob = load_robot("rx160")
    train, test = read_dataset(d / "train.csv", robot=rob), read_dataset(d / "test.csv", robot=rob)
    t0, c0 = time.perf_counter(), time.process_time()
    serial = [run_trial(rob, train, test, t, threads=1) for t in spec.trials()]
    t_serial, c_serial = time.perf_counter() - t0, time.process_time() - c0
    run_serial = t_serial  # the trials one after another (run_trial: subset, fit, evaluation)
    import ray

    t0 = time.perf_counter()
    ray.init(num_cpus=a.cpus, include_dashboard=False, logging_level="warning")
    t_init = time.perf_counter() - t0
    cpu0 = _cpu_s()
    t_call = time.time()
    t0 = time.perf_counter()
    res = run_sweep(spec, d / "out", log=lambda s: None)  # in the session started above
    t_sweep = time.perf_counter() - t0
    t_ret = time.time()
    cpu1 = _cpu_s()
    ray.shutdown()
    load1 = os.getloadavg()[0]

    tm = [r["timing"] for r in res.rows]
    same = all(r["hybrid_pos_mean_mm"] == s["hybrid_pos_mean_mm"] for r, s in zip(res.rows, serial))
    nt, slots = a.trials, t_sweep * a.cpus
    start = sum(t["t_enter"] - t["t_launch"] - t["import_s"] - t["transfer_s"] for t in tm)
    imp = sum(t["import_s"] for t in tm)
    transfer = sum(t["transfer_s"] for t in tm)
    run = sum(t["run_s"] for t in tm)
    report = sum(t["t_done"] - t["t_enter"] - t["run_s"] for t in tm)
    setup = (min(t["t_launch"] for t in tm) - t_call) * a.cpus
    end = (t_ret - max(t["t_done"] for t in tm)) * a.cpus
    busy = sum(t["t_done"] - t["t_launch"] for t in tm)
    idle = slots - busy - setup - end
    overhead = slots - run_serial
    workers = {t["pid"] for t in tm}
    dcpu = {p: cpu1[p] - cpu0.get(p, 0.0) for p in cpu1}
    cpu_driver = dcpu.pop(os.getpid(), 0.0)
    for p in workers:
        dcpu.pop(p, None)
    cpu_workers = sum(max(t["proc_cpu_s"] for t in tm if t["pid"] == p) for p in workers) - sum(t["cpu_s"] for t in tm)
    cpu_ray = sum(dcpu.values())

    print(f"load average (1 min) {load0:.1f} before, {load1:.1f} after; torch + hykin import in the serial "
          f"process {t_import:.1f} s (not in 'serial s')")
    print(f"| trials | n_train | epochs | serial s | Ray start s | sweep s ({a.cpus} CPUs) | speed-up (with Ray's start) "
          "| speed-up, both with their import | overhead per trial s | same errors |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print(f"| {nt} | {a.n} | {a.epochs} | {t_serial:.1f} | {t_init:.1f} | {t_sweep:.1f} | {t_serial / t_sweep:.2f}x "
          f"({t_serial / (t_sweep + t_init):.2f}x) | {(t_serial + t_import) / t_sweep:.2f}x | {overhead / nt:.2f} | {same} |")
    print()
    print(f"overhead per trial = (sweep wall x {a.cpus} CPUs - serial trials' run time) / trials, in s per trial:")
    print("| set-up | worker start / dispatch | import (torch+hykin) | transfer | report | end | idle slots | "
          "contention | total |")
    print("|---|---|---|---|---|---|---|---|---|")
    parts = [setup, start, imp, transfer, report, end, idle, run - run_serial]
    print("| " + " | ".join(f"{x / nt:.2f}" for x in parts) + f" | {sum(parts) / nt:.2f} |")
    print()
    print(f"CPU seconds during the sweep: trials {sum(t['cpu_s'] for t in tm):.1f} (serial run: {c_serial:.1f}); "
          f"driver {cpu_driver:.1f}; trial workers beyond their trials {cpu_workers:.1f} "
          f"({len(workers)} workers); Ray's other processes {cpu_ray:.1f}")
    print(f"trials' run time: sweep {run:.1f} s vs serial {run_serial:.1f} s "
          f"(CPU/wall in the sweep {sum(t['cpu_s'] for t in tm) / run:.2f}: below 1 = the cores were shared)")


if __name__ == "__main__":
    main()
