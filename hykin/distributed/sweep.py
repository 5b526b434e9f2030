"""`hykin sweep`: every trial of a sweep file on Ray (local or a cluster), results.csv and a plot.

:func:`run_sweep` reads the robot, training and test sets once and hands them to the trials by
reference (one ``ray.put``: one copy in Ray's object store, not one per trial; each worker reads it
once). The trials run on long-lived Ray actors (:mod:`hykin.distributed.trial_pool`: one per trial
slot of the file's [resources] CPUs/GPUs, one torch + hykin import each, one torch/numba thread per
CPU); each trial is :func:`hykin.distributed.trials.run_trial`. A trial that raises (or whose worker
dies) is run once more, then recorded with its error; it never stops the sweep. Every finished trial
is appended to ``DIR/trials.jsonl`` and ``DIR/results.csv`` is rewritten, so an interrupted sweep
keeps what finished and ``resume=True`` reruns only the trials without an ``ok`` record made with the
same inputs (each record holds ``inputs_sha256``, :func:`hykin.distributed.sweep_file.sweep_inputs_hash`:
the robot file, train / test files and ``subsample_seed``; a changed input reruns its trials).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

from .ray_session import check_resources, ray_session
from .sweep_file import SweepSpec, sweep_inputs_hash, trial_key
from .trial_pool import run_trials
from .trials import ERROR_COLUMNS, gpu_fit_options

__all__ = ["SWEEP_OUTPUTS", "SweepOutcome", "kept_records", "plot_lines", "plot_results", "run_sweep",
           "write_results"]

#: the files a sweep writes into its output folder: the results table (written through a .tmp file
#: renamed into place by :func:`write_results`), the trial records and the plot
RESULTS_CSV, RECORDS, PLOT = "results.csv", "trials.jsonl", "error_vs_n_train.png"
SWEEP_OUTPUTS = (RESULTS_CSV, RESULTS_CSV + ".tmp", RECORDS, PLOT)

RESULT_COLUMNS = ("status", "error", "attempts", *ERROR_COLUMNS, "fit_s", "eval_s", "steps", "epochs", "test_note")


@dataclass
class SweepOutcome:
    """``rows``: one dict per trial in the file's order (status ``ok``, ``error`` or ``not run``);
    ``ran``: trials run now (the others were kept from an earlier run); paths written; a row run now
    has ``timing`` (see :meth:`hykin.distributed.trial_pool.TrialWorker.run`)."""

    rows: list
    ran: int
    results_csv: Path
    plot: Path | None
    clock: dict = field(default_factory=dict)  # unix s: "start" / "end" of the trials' run

    @property
    def failed(self) -> list:
        return [r for r in self.rows if r["status"] != "ok"]


def _read_records(path: Path) -> dict:
    """key -> record ``{"key", "inputs_sha256", "row"}`` of ``trials.jsonl`` (later lines win)."""
    out = {}
    if path.is_file():
        for line in path.read_text(encoding="utf-8").splitlines():
            if line.strip():
                r = json.loads(line)
                out[r["key"]] = r
    return out


def kept_records(path: Path, inputs_sha256: str) -> tuple[dict, int]:
    """``(key -> row, n_changed)``: the rows of ``trials.jsonl`` recorded with the inputs ``inputs_sha256``
    (:func:`hykin.distributed.sweep_file.sweep_inputs_hash` now), and how many were recorded with other
    inputs (or, written before hashes were recorded, unknown ones): those are dropped, so they run again."""
    recs = _read_records(path)
    kept = {k: r["row"] for k, r in recs.items() if r.get("inputs_sha256") == inputs_sha256}
    return kept, len(recs) - len(kept)


def run_sweep(spec: SweepSpec, out_dir: str | Path, address: str | None = None, resume: bool = False,
              num_cpus: int | None = None, log=print, force: bool = False) -> SweepOutcome:
    """Run the trials of ``spec`` (when ``resume``: those without an ``ok`` record made with the same inputs) and write
    ``out_dir/results.csv`` and ``out_dir/error_vs_n_train.png``. ``log``: one progress line per call. An
    ``out_dir`` that holds an earlier sweep is refused (ValueError) unless ``resume`` or ``force`` (start
    over: its records are dropped once the trials start)."""
    from ..io.dataset_files import read_dataset
    from ..io.robot_file import load_robot
    from .files import SpecError

    out = Path(out_dir)
    records_path = out / RECORDS
    if not (resume or force) and (records_path.exists() or (out / RESULTS_CSV).exists()):
        raise ValueError(f"{out}: holds an earlier sweep (results.csv); use --resume to finish it, --force to start "
                         "it over, or another -o")
    trials = spec.trials()
    keys = [trial_key(t) for t in trials]
    inputs = sweep_inputs_hash(spec)  # the robot / train / test files and subsample_seed as the trials start
    records, n_changed = kept_records(records_path, inputs) if resume else ({}, 0)
    todo = [i for i, k in enumerate(keys) if records.get(k, {}).get("status") != "ok"]
    rob = load_robot(spec.robot)
    units = {"length_unit": spec.length_unit, "angle_unit": spec.angle_unit}  # as `hykin fit --length-unit ...`
    train = read_dataset(spec.train, robot=rob, **units)
    test = read_dataset(spec.test, robot=rob, **units)
    n_max = max((t.get("n_train", 0) for t in trials), default=0)
    if n_max > len(train):
        raise SpecError(f"{spec.path}: n_train = {n_max} exceeds the {len(train)} rows of {spec.train}")
    columns = list(dict.fromkeys(k for t in trials for k in t))

    def rows_now():
        rows = []
        for i, (t, k) in enumerate(zip(trials, keys)):
            r = records.get(k) or {"status": "not run", "error": "", "attempts": 0}
            rows.append({"trial": i, **t, **r})
        return rows

    t_start, n_done, clock = time.perf_counter(), [0], {}

    def on_done(i, row):
        records[keys[i]] = row
        with open(records_path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps({"key": keys[i], "inputs_sha256": inputs, "row": row}) + "\n")
        write_results(out / RESULTS_CSV, rows_now(), columns)
        n_done[0] += 1
        el = time.perf_counter() - t_start
        eta = el / n_done[0] * (len(todo) - n_done[0])
        opts = " ".join(f"{k}={v}" for k, v in trials[i].items())
        what = (f"hybrid {row['hybrid_pos_mean_mm']:.4f} mm, fit {row['fit_s']:.1f} s"
                + (" (test poses outside its training range: test_note)" if row.get("test_note") else "")
                if row["status"] == "ok" else f"FAILED after {row['attempts']} attempts: {row['error']}")
        log(f"sweep: trial {n_done[0]}/{len(todo)} done (#{i} {opts}): {what}; elapsed {el:.0f} s, ETA {eta:.0f} s")

    if resume:
        if n_changed:
            log(f"sweep: {n_changed} recorded trials of {records_path} were run on other (or unrecorded) inputs (robot file, train / "
                "test data or subsample_seed changed since): they run again")
        log(f"sweep: {len(trials) - len(todo)} of {len(trials)} trials kept from {records_path}, {len(todo)} to run")
    if todo:
        with ray_session(address, num_cpus) as ray:
            check_resources(ray, str(spec.path), {"cpus_per_trial": spec.cpus_per_trial,
                                                  "gpus_per_trial": spec.gpus_per_trial}, address)
            out.mkdir(parents=True, exist_ok=True)  # after every check: a refused sweep writes nothing
            if force and not resume:  # started over: the earlier sweep's records go (a later --resume keeps none)
                records_path.unlink(missing_ok=True)
            clock["start"] = time.time()
            # the recorded options stay as written (so --resume keys do not change); the fit gets the device
            run_trials(ray, {i: gpu_fit_options(trials[i], spec.gpus_per_trial) for i in todo}, (rob, train, test),
                       spec.cpus_per_trial, spec.gpus_per_trial, spec.subsample_seed, on_done)
            clock["end"] = time.time()
    rows = rows_now()
    out.mkdir(parents=True, exist_ok=True)
    write_results(out / RESULTS_CSV, rows, columns)
    plot = plot_results(rows, out / PLOT)
    return SweepOutcome(rows=rows, ran=len(todo), results_csv=out / RESULTS_CSV, plot=plot, clock=clock)


def write_results(path: Path, rows: list, option_columns: list) -> None:
    """``results.csv``: trial, the options, RESULT_COLUMNS (empty cells where a trial has no value),
    written by the one CSV writer (:func:`hykin.io.csv_writer.write_csv`, rows style)."""
    import numpy as np

    from ..io.csv_writer import ROWS_STYLE, write_csv

    names = ["trial", *option_columns, *(c for c in RESULT_COLUMNS if c not in option_columns)]
    if any("n_train" in r for r in rows) and "n_train" not in names:
        names.insert(1 + len(option_columns), "n_train")
    cols = {}
    for c in names:
        vals = [r.get(c, "") for r in rows]
        cols[c] = np.array(["" if v is None or (isinstance(v, float) and math.isnan(v) and c not in ERROR_COLUMNS)
                            else v for v in vals], dtype=object)
    tmp = path.with_suffix(".csv.tmp")
    write_csv(tmp, cols, ROWS_STYLE)
    tmp.replace(path)


#: options that change only the networks, not the calibration (a calibrated-only line is one per the other options)
NET_OPTIONS = ("arch", "recipe", "seed", "device", "max_minutes", "min_steps", "max_epochs")


def _option(row: dict, key: str):
    """``row``'s value of option ``key`` (its `hykin fit` default where the row's grid does not give it)."""
    from ..hybrid.fit_options import FIT_OPTIONS

    return row.get(key, FIT_OPTIONS.get(key))


def _grouped(rows: list, keys: list, column: str) -> list:
    """``[(label, ns, ys)]``: ``rows`` grouped by their values of ``keys`` (label ``k=v, ...``, first-seen
    order), each group's finite ``column`` values averaged per ``n_train`` (sorted)."""
    import numpy as np

    groups: dict = {}
    for r in rows:
        v = r[column]
        if v is not None and math.isfinite(v):
            groups.setdefault(tuple(_option(r, k) for k in keys), {}).setdefault(int(r["n_train"]), []).append(v)
    out = []
    for vals, by_n in groups.items():
        ns = sorted(by_n)
        label = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in zip(keys, vals))
        out.append((label, ns, [float(np.mean(by_n[n])) for n in ns]))
    return out


def plot_lines(rows: list) -> tuple[list, str]:
    """What :func:`plot_results` draws: ``([(label, ns, ys, calibrated)], title)``. One hybrid line
    (``calibrated`` False) per combination of the options that differ between the finished trials other
    than ``n_train`` and ``seed``; each point the mean over the seeds (the title says which), never over
    other differing options (calibrate true and false are separate lines). One calibrated-only line per
    combination of those options that act on the calibration (not :data:`NET_OPTIONS`), from the trials
    that calibrated. ``ys``: test position error, mean over the test poses (mm)."""
    from .options import OPTION_TYPES

    ok = [r for r in rows if r["status"] == "ok"]
    varying = [k for k in OPTION_TYPES if k != "n_train" and len({repr(_option(r, k)) for r in ok}) > 1]
    keys = [k for k in varying if k != "seed"]
    lines = [(label or "hybrid", ns, ys, False) for label, ns, ys in _grouped(ok, keys, "hybrid_pos_mean_mm")]
    cal_keys = [k for k in keys if k not in NET_OPTIONS]
    lines += [("calibrated only" + (f" ({label})" if label else ""), ns, ys, True)
              for label, ns, ys in _grouped(ok, cal_keys, "calibrated_pos_mean_mm")]
    if "seed" in varying:
        title = "each point: mean over seed " + ", ".join(str(s) for s in sorted({_option(r, "seed") for r in ok}))
    else:
        cells = {(repr([_option(r, k) for k in keys]), r["n_train"]) for r in ok}
        title = "each point: one trial" if len(cells) == len(ok) else "each point: mean of its repeated trials"
    return lines, title


def plot_results(rows: list, path: Path) -> Path | None:
    """Test error against training-set size (log-log), the lines of :func:`plot_lines`: hybrid solid, one
    per combination of the differing options (labelled), calibrated-only dashed; the title says what each
    point averages. None when no trial finished."""
    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines, title = plot_lines(rows)
    fig, ax = plt.subplots(figsize=(7.2, 4.8))
    markers = iter("sv^D<>ph*" * 4)
    for label, ns, ys, calibrated in lines:
        if calibrated:
            ax.plot(ns, ys, "--", color="k", marker=next(markers), label=label)
        else:
            ax.plot(ns, ys, "o-", label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("training samples")
    ax.set_ylabel("test position error, mean over test poses (mm)")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
