"""`hykin fleet`: fit, evaluate and register many robots in parallel, one Ray task per robot.

Each robot (:class:`hykin.distributed.fleet_file.FleetRobot`) is one task, :func:`robot_job`: fit
(:func:`hykin.distributed.trials.fit_model`, the `hykin fit` path), the model file ``DIR/<name>.hykin``,
evaluate on its test set (nominal / calibrated / hybrid), and where a series is given register it
(:func:`hykin.measure.register.register_model`, the `hykin register` path), evaluate the registered model
on the series' poses not used to register it (none when ``poses`` covers the series: the registered error
is then left empty, NaN, and ``n_registered_held_out`` is 0), and write ``DIR/<name>-registered.hykin`` (the files come
back to the driver as bytes, which writes them, so the output folder need not be shared with the workers). A robot that fails is a row with its error; the others go on.
Writes ``DIR/summary.csv`` (the one CSV writer) and ``DIR/summary.md`` (a markdown table).

``resume=True`` keeps a robot whose ``summary.csv`` row is ``ok``, whose model files are in ``DIR`` and
whose ``inputs_sha256`` (:func:`inputs_hash`: robot file, data files, poses, fit options) is unchanged;
the others run again. An output folder that holds an earlier fleet (its summary or a model file the
fleet writes, :func:`fleet_outputs`) is refused before Ray starts unless ``resume`` or ``force`` (fit
every robot again, overwriting them), as `hykin sweep` refuses an earlier sweep.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from .files import inputs_sha256
from .fleet_file import FleetRobot, FleetSpec
from .options import units_options
from .ray_session import check_resources, ray_session
from .trial_pool import first_line
from .trials import ERROR_COLUMNS, error_columns, evaluate_noted, fit_model, gpu_fit_options

__all__ = ["SUMMARY_COLUMNS", "fleet_outputs", "inputs_hash", "kept_rows", "registered_note", "robot_job", "run_fleet", "summary_markdown"]

SUMMARY_COLUMNS = ("name", "status", "error", "n_train", "n_test", *ERROR_COLUMNS, "fit_s",
                   "registered_hybrid_pos_mean_mm", "registered_hybrid_ang_mean_deg", "n_registered_held_out", "model",
                   "registered_model", "test_note", "inputs_sha256")


def _model_bytes(model) -> bytes:
    """The model file's bytes (written on the worker, sent to the driver that writes the output folder)."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "model.hykin"
        model.save(path)
        return path.read_bytes()


def robot_job(entry: FleetRobot) -> dict:
    """Fit / evaluate / register one robot; a summary row (status ``ok`` or ``failed`` with ``error``).
    The model files come back as bytes in ``files`` (file name -> bytes) for the driver to write."""
    from ..io.dataset_files import read_dataset
    from ..io.robot_file import load_robot
    from ..measure.register import register_model

    row = {"name": entry.name, "status": "ok", "error": "", "files": {}}
    try:
        rob = load_robot(entry.robot)
        units = {"length_unit": entry.length_unit, "angle_unit": entry.angle_unit}  # as `hykin fit --length-unit ...`
        train = read_dataset(entry.train, robot=rob, **units)
        t0 = time.perf_counter()
        model = fit_model(rob, train, entry.fit)
        row.update(n_train=len(train), fit_s=time.perf_counter() - t0)
        row["model"] = f"{entry.name}.hykin"
        row["files"][row["model"]] = _model_bytes(model)
        if entry.test is not None:
            test = read_dataset(entry.test, robot=rob, **units)
            res, note = evaluate_noted(model, test)
            row.update(n_test=len(test), **error_columns(res), test_note=note)
        if entry.register is not None:
            series = read_dataset(entry.register, robot=rob, **units)
            new, info = register_model(model, series, n_poses=entry.poses)
            row["registered_model"] = f"{entry.name}-registered.hykin"
            row["files"][row["registered_model"]] = _model_bytes(new)
            rest = np.setdiff1d(np.arange(len(series)), info.used_index)  # the poses not used to register
            row.update(registered_hybrid_pos_mean_mm=float("nan"), registered_hybrid_ang_mean_deg=float("nan"),
                       n_registered_held_out=int(rest.size))
            if rest.size:  # no held-out poses (poses >= the series' length): no held-out error, left empty
                res, _ = evaluate_noted(new, series.subset(rest))
                ev = error_columns(res)
                row.update(registered_hybrid_pos_mean_mm=ev["hybrid_pos_mean_mm"],
                           registered_hybrid_ang_mean_deg=ev["hybrid_ang_mean_deg"])
    except Exception as e:  # noqa: BLE001 - a failing robot is recorded; the fleet goes on
        row.update(status="failed", error=first_line(e), files={})
    return row


def inputs_hash(entry: FleetRobot) -> str:
    """SHA-256 over what a robot's results depend on (:func:`hykin.distributed.files.inputs_sha256`): the
    robot file's bytes (a preset: its name), the train / test / register files' bytes, ``poses``, the fit options
    and the data units (when not m / rad: a fleet recorded before the unit keys keeps its hashes)."""
    return inputs_sha256((entry.robot, entry.train, entry.test, entry.register),
                         {"poses": entry.poses, "fit": entry.fit, **units_options(entry.length_unit, entry.angle_unit)})


def kept_rows(spec: FleetSpec, out: Path) -> dict:
    """name -> earlier summary row (numbers as floats) of each robot that need not run again: status
    ``ok``, its model file(s) in ``out`` and its ``inputs_sha256`` equal to :func:`inputs_hash` now."""
    import csv

    path = out / "summary.csv"
    if not path.is_file():
        return {}
    with open(path, newline="", encoding="utf-8") as fh:
        old = {r.get("name"): r for r in csv.DictReader(fh)}
    keep = {}
    for e in spec.robots:
        r = old.get(e.name)
        if (r is None or r.get("status") != "ok" or r.get("inputs_sha256") != inputs_hash(e)
                or not (out / f"{e.name}.hykin").is_file()
                or (e.register is not None and not (out / f"{e.name}-registered.hykin").is_file())):
            continue
        row = {k: v if k in ("name", "status", "error", "model", "registered_model", "inputs_sha256") else _number(v)
               for k, v in r.items()}
        keep[e.name] = row
    return keep


def _number(text: str):
    """A summary cell as written: int, float, or the text itself (empty cells stay empty)."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def fleet_outputs(spec: FleetSpec) -> list:
    """The file names a fleet writes into its output folder: ``summary.csv``, ``summary.md`` and each
    robot's ``NAME.hykin`` (and ``NAME-registered.hykin`` where it registers a series)."""
    names = ["summary.csv", "summary.md"]
    for r in spec.robots:
        names += [f"{r.name}.hykin"] + ([f"{r.name}-registered.hykin"] if r.register is not None else [])
    return names


def run_fleet(spec: FleetSpec, out_dir: str | Path, address: str | None = None, num_cpus: int | None = None,
              log=print, resume: bool = False, force: bool = False) -> list:
    """Run every robot of ``spec`` as a Ray task (retried once if its worker dies); write the per-robot
    model files, ``summary.csv`` and ``summary.md`` into ``out_dir``. ``resume``: keep the robots of
    :func:`kept_rows`. ValueError (one line) when ``out_dir`` holds an earlier fleet's files and neither
    ``resume`` nor ``force`` is given. Returns the rows in file order."""
    out = Path(out_dir)
    if not (resume or force):
        earlier = [n for n in fleet_outputs(spec) if (out / n).exists()]
        if earlier:
            more = f" and {len(earlier) - 3} more" if len(earlier) > 3 else ""
            raise ValueError(f"{out}: holds an earlier fleet ({', '.join(earlier[:3])}{more}); use --resume to finish "
                             "it, --force to fit every robot again over it, or another -o")
    rows: dict = kept_rows(spec, out) if resume else {}
    if resume:
        log(f"fleet: {len(rows)} of {len(spec.robots)} robots kept from {out / 'summary.csv'}, "
            f"{len(spec.robots) - len(rows)} to run")
    todo = [r for r in spec.robots if r.name not in rows]
    if todo:
        _run_robots(spec, todo, out, rows, address, num_cpus, log)
    ordered = [rows[r.name] for r in spec.robots]
    out.mkdir(parents=True, exist_ok=True)
    _write_summary(out / "summary.csv", ordered)
    (out / "summary.md").write_text(summary_markdown(ordered), encoding="utf-8")
    return ordered


def _run_robots(spec: FleetSpec, todo: list, out: Path, rows: dict, address, num_cpus, log) -> None:
    """The robots ``todo`` as Ray tasks; each finished robot's files written and its row put in ``rows``."""
    hashes = {r.name: inputs_hash(r) for r in todo}  # the inputs as they are when the robots start
    t0, n_done = time.perf_counter(), 0
    with ray_session(address, num_cpus) as ray:
        check_resources(ray, str(spec.path), {"cpus_per_robot": spec.cpus_per_robot,
                                              "gpus_per_robot": spec.gpus_per_robot}, address)
        out.mkdir(parents=True, exist_ok=True)  # after every check: a refused fleet writes nothing
        job = ray.remote(num_cpus=spec.cpus_per_robot, num_gpus=spec.gpus_per_robot, max_retries=1)(robot_job)
        pending = {job.remote(dataclasses.replace(r, fit=gpu_fit_options(r.fit, spec.gpus_per_robot))): r for r in todo}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            entry = pending.pop(done[0])
            name = entry.name
            try:
                row = ray.get(done[0])
            except Exception as e:  # noqa: BLE001 - the worker died twice: recorded, the others go on
                row = {"name": name, "status": "failed", "error": first_line(e)}
            row["inputs_sha256"] = hashes[name]
            if row["status"] != "ok":  # no model of an earlier run left beside a failed row
                for stale in (out / f"{name}.hykin", out / f"{name}-registered.hykin"):
                    stale.unlink(missing_ok=True)
            for fname, data in row.pop("files", {}).items():
                (out / fname).write_bytes(data)
            rows[name] = row
            n_done += 1
            _write_summary(out / "summary.csv", [rows[r.name] for r in spec.robots if r.name in rows])  # resumable
            if row["status"] != "ok":
                what = f"FAILED: {row['error']}"
            elif row.get("hybrid_pos_mean_mm") is None:
                what = "fitted (no test set: no test errors)"
            else:
                what = f"hybrid {row['hybrid_pos_mean_mm']:.4f} mm on its test set"
            what += registered_note(row)
            log(f"fleet: robot {n_done}/{len(todo)} {name}: {what}; elapsed {time.perf_counter() - t0:.0f} s")


def registered_note(row: dict) -> str:
    """The progress line's words on a robot's registered model: its error on the held-out poses of the
    series, or that none were held out (every pose of the series registered it: no held-out error)."""
    if row.get("registered_model") in (None, ""):
        return ""
    n, err = row.get("n_registered_held_out"), row.get("registered_hybrid_pos_mean_mm")
    if not n or err is None or err != err:
        return ", registered (no held-out poses: every pose of the series was used to register, no held-out error)"
    return f", registered series {err:.4f} mm on {n} held-out poses"


def _write_summary(path: Path, rows: list) -> None:
    from ..io.csv_writer import ROWS_STYLE, write_csv

    write_csv(path, {c: np.array([r.get(c, "") for r in rows], dtype=object) for c in SUMMARY_COLUMNS}, ROWS_STYLE)


def summary_markdown(rows: list) -> str:
    """A markdown table of the fleet: robot, status, nominal / calibrated / hybrid mean errors (mm) on
    its test set, the registered model's error on the poses of its new series not used to register it
    and how many those are (blank error when none), fit time, and the failures."""
    def f(r, k, fmt="{:.4f}"):
        v = r.get(k, "")
        return "" if v == "" or v != v else fmt.format(v)

    lines = ["# hykin fleet summary", "",
             "| robot | status | nominal mm | calibrated mm | hybrid mm | registered hybrid mm (held out) "
             "| registered held-out poses | fit s |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['status']} | {f(r, 'nominal_pos_mean_mm')} | {f(r, 'calibrated_pos_mean_mm')} | "
                     f"{f(r, 'hybrid_pos_mean_mm')} | {f(r, 'registered_hybrid_pos_mean_mm')} | "
                     f"{f(r, 'n_registered_held_out', '{:.0f}')} | {f(r, 'fit_s', '{:.1f}')} |")
    failed = [r for r in rows if r["status"] != "ok"]
    if failed:
        lines += ["", "Failures:", ""] + [f"- {r['name']}: {r['error']}" for r in failed]
    return "\n".join(lines) + "\n"
