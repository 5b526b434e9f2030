"""The ``hykin`` command line (DESIGN.md §4).

Every command turns bad input into a one-line error on stderr and a non-zero exit status; no
tracebacks. Heavy imports (torch) happen inside the commands that need them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import numpy as np
import typer

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="hykin: high-accuracy hybrid kinematics for serial robot arms (classical model + calibration + residual networks).",
)

LengthUnit = typer.Option("m", "--length-unit", help="Unit of x,y,z in the input files: m or mm.")
AngleUnit = typer.Option("rad", "--angle-unit", help="Unit of joint columns in the input files: rad or deg.")


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def _console():
    from rich.console import Console

    return Console(stderr=True)


def _progress():
    """A rich progress bar writing to stderr (disabled when stderr is not a terminal and CI is set)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=_console(),
        transient=False,
    )


def _is_model_file(spec: str) -> bool:
    p = Path(spec)
    if not p.is_file():
        return False
    with open(p, "rb") as f:
        head = f.read(8)
    # safetensors files start with an 8-byte little-endian header length followed by '{'
    if len(head) < 8:
        return False
    n = int.from_bytes(head, "little")
    return 0 < n < 100_000_000 and p.suffix.lower() not in (".toml", ".urdf", ".csv")


def _load_model_or_robot(spec: str):
    """Return ``(model_or_None, robot)`` for a model file, a robot file or a preset name."""
    from .robot import load_robot

    if _is_model_file(spec):
        from .hybrid import HybridModel

        model = HybridModel.load(spec)
        return model, model.robot
    return None, load_robot(spec)


# --------------------------------------------------------------------------- commands


@app.command("presets")
def presets_cmd() -> None:
    """List the robot presets and the virtual-robot presets shipped with hykin."""
    from .robot import list_presets, load_robot

    typer.echo("robot presets (use as ROBOT):")
    for name in list_presets():
        r = load_robot(name)
        typer.echo(f"  {name:16s} {r.dof} dof, {r.convention}")
    try:
        from .simulate import list_virtual_presets, virtual_preset

        typer.echo("virtual robots (use with `hykin simulate`):")
        for name in list_virtual_presets():
            desc = (virtual_preset(name).description or "").strip().splitlines()
            typer.echo(f"  {name:16s} {desc[0] if desc else ''}")
    except ImportError:  # pragma: no cover
        pass


@app.command("simulate")
def simulate_cmd(
    preset: str = typer.Argument(..., help="Virtual robot preset, e.g. rx160-virtual (see `hykin presets`)."),
    n: int = typer.Option(10_000, "-n", help="Number of samples.", min=1),
    out: Path = typer.Option(..., "-o", "--out", help="Output dataset (.csv or .parquet); truth saved beside it."),
    seed: int = typer.Option(0, "--seed", help="Random seed (reproducible)."),
    plan: str = typer.Option("uniform", "--plan", help="Sampling plan: uniform, random, zigzag, iso-cube, restricted."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Add tracker-like measurement noise."),
) -> None:
    """Simulate a measured dataset from a virtual robot whose truth is known."""
    from .simulate import simulate_to_file

    with _progress() as prog:
        task = prog.add_task(f"simulating {preset}", total=n)
        info = simulate_to_file(
            preset, n, out, plan=plan.replace("-", "_"), seed=seed, noise=noise,
            progress=lambda done, total: prog.update(task, completed=done, total=total),
        )
    typer.echo(f"wrote {n} samples to {out}" + (f" (truth: {info})" if info else ""))


@app.command("import")
def import_cmd(
    kind: str = typer.Argument(..., help="Source format: ur5 (serial-robots-ur5 CSV) or ipa (ipa-robot-accuracy Series_X folder)."),
    path: Path = typer.Argument(..., help="File or folder to import."),
    out: Path = typer.Option(..., "-o", "--out", help="Output dataset in the standard format (.csv/.parquet)."),
    register: bool = typer.Option(
        False, "--register/--tracker-frame",
        help="ipa: express poses in the robot base by a rigid base+tool fit of the nominal UR10 (default: keep the tracker frame).",
    ),
    robot_out: Optional[Path] = typer.Option(
        None, "--robot-out", help="Also write the nominal robot file matching this data (tool/TCP of the setup)."
    ),
) -> None:
    """Import a real measurement series into the standard dataset format."""
    from .dataset import write_dataset
    from .importers import import_ipa_series, import_ur5, ipa_nominal_robot, ur5_robot_for_dataset
    from .robot import save_robot_toml

    if kind == "ur5":
        ds = import_ur5(path)
        robot = ur5_robot_for_dataset()
    elif kind == "ipa":
        robot = ipa_nominal_robot()
        ds = import_ipa_series(path, register_to=ipa_nominal_robot() if register else None)
    else:
        raise CLIError(f"import: unknown format {kind!r}; expected ur5 or ipa")
    write_dataset(ds, out)
    frame = ds.meta.get("frame", "robot base")
    typer.echo(f"wrote {len(ds)} samples to {out} (poses in the {frame} frame)")
    if robot_out is not None:
        save_robot_toml(robot, robot_out)
        typer.echo(f"wrote the matching nominal robot to {robot_out}")


@app.command("split")
def split_cmd(
    data: Path = typer.Argument(..., help="Dataset to split (.csv/.parquet)."),
    out_prefix: Path = typer.Option(..., "-o", "--out", help="Output prefix: writes PREFIX_train.csv and PREFIX_test.csv."),
    test: float = typer.Option(0.2, "--test", help="Fraction held out for testing.", min=0.01, max=0.99),
    seed: int = typer.Option(0, "--seed"),
    group: Optional[str] = typer.Option(None, "--group", help="Keep rows with the same value of this column together."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Random train/test split of a dataset (disjoint, reproducible)."""
    from .dataset import read_dataset, split, write_dataset

    ds = read_dataset(data, length_unit=length_unit, angle_unit=angle_unit)
    tr, te = split(ds, (1.0 - test, test), seed=seed, group=group)
    suffix = data.suffix if data.suffix in (".csv", ".parquet") else ".csv"
    paths = [Path(f"{out_prefix}_train{suffix}"), Path(f"{out_prefix}_test{suffix}")]
    write_dataset(tr, paths[0])
    write_dataset(te, paths[1])
    typer.echo(f"wrote {len(tr)} training rows to {paths[0]} and {len(te)} test rows to {paths[1]}")


@app.command("fit")
def fit_cmd(
    robot: str = typer.Argument(..., help="Robot file (.toml), URDF, or preset name."),
    train: Path = typer.Argument(..., help="Training dataset (.csv/.parquet)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output model file (one safetensors file)."),
    val: Optional[Path] = typer.Option(None, "--val", help="Validation dataset (default: 10% of TRAIN held out)."),
    arch: str = typer.Option("default", "--arch", help="Network architecture: default, D1, D4, D4w, D4W, Rw, Rd, B1..B4."),
    recipe: str = typer.Option("default", "--recipe", help="Training recipe: default or paper."),
    calibrate: bool = typer.Option(True, "--calibrate/--no-calibrate", help="Parametric calibration before the networks."),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda, or auto."),
    seed: int = typer.Option(0, "--seed"),
    max_minutes: Optional[float] = typer.Option(None, "--max-minutes", help="Time budget for network training."),
    thermal: str = typer.Option("auto", "--thermal", help="Thermal expansion from a temperature_c column: auto, on, off."),
    min_steps: Optional[int] = typer.Option(None, "--min-steps", help="Least number of optimiser steps per network (default recipe: 30000)."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Fit a hybrid model: calibrate the classical model, then train the residual networks."""
    from .dataset import read_dataset, split
    from .hybrid import HybridModel
    from .robot import load_robot

    rob = load_robot(robot)
    tr = read_dataset(train, length_unit=length_unit, angle_unit=angle_unit, robot=rob)
    if val is not None:
        va = read_dataset(val, length_unit=length_unit, angle_unit=angle_unit, robot=rob)
    else:
        tr, va = split(tr, (0.9, 0.1), seed=seed)
    if device == "auto":
        import torch

        device = "cuda" if torch.cuda.is_available() else "cpu"
    kw = {}
    if max_minutes is not None:
        kw["max_seconds"] = max_minutes * 60
    if min_steps is not None:
        if min_steps < 0:
            raise CLIError(f"--min-steps must be >= 0, got {min_steps}")
        kw["recipe_kw"] = {"min_steps": min_steps}
    modes = {"auto": "auto", "on": True, "off": False}
    if thermal not in modes:
        raise CLIError(f"--thermal must be auto, on or off, got {thermal!r}")
    model = HybridModel(rob, arch=arch, recipe=recipe, calibrate=calibrate, device=device, seed=seed,
                        thermal=modes[thermal], **kw)
    model.fit(tr, va, progress=True)
    model.save(out)
    if model.thermal_ is not None:
        typer.echo(f"thermal expansion: {model.thermal_.note} (reference {model.thermal_.reference_c:.2f} °C)")
    _print_metrics(model)
    typer.echo(f"model written to {out}")


def _print_metrics(model) -> None:
    """One line per evaluated set: calibrated vs hybrid mean errors (mm, deg)."""
    metrics = (getattr(model, "metadata", None) or {}).get("metrics") or {}
    for name, m in metrics.items():
        line = f"{name}: calibrated {m.get('classical_pos_mean_mm', float('nan')):.4f} mm"
        if "classical_rot_mean_deg" in m:
            line += f" / {m['classical_rot_mean_deg']:.4f} deg"
        line += f" -> hybrid {m.get('hybrid_pos_mean_mm', float('nan')):.4f} mm"
        if "hybrid_rot_mean_deg" in m:
            line += f" / {m['hybrid_rot_mean_deg']:.4f} deg"
        typer.echo(line + " (mean)")


@app.command("fk")
def fk_cmd(
    model: str = typer.Argument(..., help="Model file, robot file, URDF or preset (nominal FK)."),
    joints: Path = typer.Argument(..., help="CSV/Parquet with columns q1..qN."),
    out: Path = typer.Option(..., "-o", "--out", help="Output poses (dataset columns q…, x,y,z,qw,qx,qy,qz)."),
    angle_unit: str = AngleUnit,
    no_fade: bool = typer.Option(False, "--no-fade", help="Apply the network correction even outside the training region."),
) -> None:
    """Forward kinematics: full hybrid model for a model file, classical FK for a robot."""
    from .dataset import Dataset, read_joints, write_dataset
    from .fk import fk

    mdl, rob = _load_model_or_robot(model)
    q, extra = read_joints(joints, dof=rob.dof, angle_unit=angle_unit, robot=rob)
    if mdl is None:
        T = fk(rob, q)
    else:
        if no_fade:
            mdl.fade = False
        temp = _temperature(mdl, extra, joints)
        T = mdl.predict(q, temperature_c=temp)
        extra = dict(extra)
        extra["support_distance"] = mdl.support_distance(q)
        band_mm, band_deg = mdl.predict_uncertainty(q, temperature_c=temp)
        extra["pos_band95_mm"] = band_mm
        if band_deg is not None:
            extra["ang_band95_deg"] = band_deg
    write_dataset(Dataset.from_poses(q, T, extra=extra, source=str(joints)), out)
    typer.echo(f"wrote {len(q)} poses to {out}")


@app.command("ik")
def ik_cmd(
    model: str = typer.Argument(..., help="Model file (hybrid IK) or robot file / preset (classical IK)."),
    poses: Path = typer.Argument(..., help="Target poses: x,y,z[,qw,qx,qy,qz] (m)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output joints CSV: target, branch, q…, errors."),
    all_branches: bool = typer.Option(False, "--all-branches", help="Every solution branch, not only the nearest one."),
    seed_joints: Optional[Path] = typer.Option(None, "--seed-joints", help="CSV of current joints (one row per target, or one row)."),
    position_only: bool = typer.Option(False, "--position-only", help="Solve for position only."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Inverse kinematics: every branch (or the one nearest the seed joints), failures reported."""
    from .dataset import read_joints, read_poses

    mdl, rob = _load_model_or_robot(model)
    T, has_rot, pose_extra = read_poses(poses, length_unit=length_unit, extras=True)
    position_only = position_only or not has_rot
    q_cur = None
    if seed_joints is not None:
        q_cur, _ = read_joints(seed_joints, dof=rob.dof, angle_unit=angle_unit, robot=rob)
        if len(q_cur) == 1:
            q_cur = np.repeat(q_cur, len(T), axis=0)
        elif len(q_cur) != len(T):
            raise CLIError(f"{seed_joints}: {len(q_cur)} rows, expected 1 or {len(T)} (one per target)")
    nearest = not all_branches
    if nearest and q_cur is None:
        q_cur = np.zeros((len(T), rob.dof))  # nearest to the zero pose when no seed is given
    if mdl is None:
        rows = _classical_ik_rows(rob, T, q_cur if nearest else None, position_only)
    else:
        from .hybrid_ik import hybrid_ik, ik_result_to_rows

        target = T[:, :3, 3] if position_only else T
        res = hybrid_ik(mdl, target, all_branches=True, q_current=q_cur, nearest=nearest, position_only=position_only,
                        temperature_c=_temperature(mdl, pose_extra, poses))
        rows = ik_result_to_rows(res)
        from .hybrid import support_report

        has_q = np.isfinite(res.q).all(axis=1)
        msg = support_report(mdl, res.q[has_q])["message"] if has_q.any() else ""
        if msg:
            _console().print(f"[yellow]warning:[/] {msg} (see the in_support column)")
    _write_rows(rows, out)
    ok = np.asarray(rows["success"], dtype=bool)
    n_targets = len(T)
    solved = len(set(np.asarray(rows["target"])[ok].tolist()))
    typer.echo(f"wrote {len(ok)} solution rows for {n_targets} targets to {out} ({solved} solved, {n_targets - solved} failed)")


def _temperature(mdl, extra: dict, path) -> np.ndarray | None:
    """The file's temperature column for a model with a thermal coefficient (note when it is missing)."""
    from .thermal import temperature_from

    th = getattr(mdl, "thermal_", None)
    if th is None or th.coefficient_per_k == 0.0:
        return None
    t = temperature_from(extra, str(path))
    if t is None:
        _console().print(f"[yellow]note:[/] the model compensates thermal expansion ({th.coefficient_per_k * 1e6:.2f} µm/m/K) "
                         f"but {path} has no temperature_c column: results at the reference {th.reference_c:.2f} °C")
    return t


def _classical_ik_rows(robot, T, q_current, position_only: bool) -> dict:
    """Rows for classical IK on a robot: every branch, or the one nearest ``q_current``."""
    from .ik import ik

    br = ik(robot, T, all_branches=True, position_only=position_only)
    if q_current is not None:
        r = br.nearest_to(q_current, robot.lower, robot.upper)
        q, ok, pe, ae, lab = r.q[:, None], r.success[:, None], r.pos_err_m[:, None], r.ang_err_rad[:, None], np.asarray(r.label)[:, None]
    else:
        q, ok, pe, ae, lab = br.q, br.success, br.pos_err_m, br.ang_err_rad, br.label
    N, K, n = q.shape
    rows: dict = {"target": [], "branch": []}
    rows.update({f"q{j + 1}": [] for j in range(n)})
    rows.update({"success": [], "pos_err_mm": [], "ang_err_deg": [], "reason": []})
    for i in range(N):
        ks = [k for k in range(K) if ok[i, k]]
        if not ks:  # unreachable: one row saying so, no made-up joints
            rows["target"].append(i)
            rows["branch"].append("")
            for j in range(n):
                rows[f"q{j + 1}"].append(float("nan"))
            rows["success"].append(False)
            rows["pos_err_mm"].append(float(np.nanmin(pe[i]) * 1e3) if np.isfinite(pe[i]).any() else float("nan"))
            rows["ang_err_deg"].append(float(np.degrees(np.nanmin(ae[i]))) if np.isfinite(ae[i]).any() else float("nan"))
            rows["reason"].append("unreachable: no solution within joint limits")
            continue
        for k in ks:
            rows["target"].append(i)
            rows["branch"].append(str(lab[i, k]))
            for j in range(n):
                rows[f"q{j + 1}"].append(float(q[i, k, j]))
            rows["success"].append(True)
            rows["pos_err_mm"].append(float(pe[i, k] * 1e3))
            rows["ang_err_deg"].append(float(np.degrees(ae[i, k])))
            rows["reason"].append("")
    return rows


def _write_rows(rows: dict, out: Path) -> None:
    import csv

    keys = list(rows)
    cols = [np.asarray(rows[k]) for k in keys]
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(keys)
        for i in range(len(cols[0]) if cols else 0):
            w.writerow([_fmt(c[i]) for c in cols])


def _fmt(v) -> str:
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    return str(v)


@app.command("evaluate")
def evaluate_cmd(
    model: str = typer.Argument(..., help="Model file (or a robot: classical only)."),
    test: Path = typer.Argument(..., help="Test dataset (.csv/.parquet)."),
    as_json: bool = typer.Option(False, "--json", help="Print the table as JSON."),
    report: Optional[Path] = typer.Option(None, "--report", help="Write an HTML report with plots to this directory."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Before/after error table (mean, std, p95, max; position mm, orientation deg)."""
    from .dataset import read_dataset
    from .evaluate import evaluate_model, evaluation_report

    mdl, rob = _load_model_or_robot(model)
    ds = read_dataset(test, length_unit=length_unit, angle_unit=angle_unit, robot=rob)
    res = evaluate_model(mdl if mdl is not None else rob, ds)
    if as_json:
        typer.echo(json.dumps(res.to_dict(), indent=2))
    else:
        typer.echo(res.table())
    if report is not None:
        path = evaluation_report(res, report)
        typer.echo(f"report written to {path}")


@app.command("calibrate")
def calibrate_cmd(
    robot: str = typer.Argument(..., help="Robot file (.toml), URDF, or preset name."),
    data: Path = typer.Argument(..., help="Measured dataset (.csv/.parquet)."),
    out: Path = typer.Option(..., "-o", "--out", help="Calibrated robot file (.toml)."),
    compliance: bool = typer.Option(True, "--compliance/--no-compliance", help="Identify joint compliance under gravity."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Parametric calibration only (geometry, base, tool, joint compliance); writes a robot file."""
    from .calibrate import calibrate
    from .dataset import read_dataset
    from .robot import load_robot, save_robot_toml

    rob = load_robot(robot)
    ds = read_dataset(data, length_unit=length_unit, angle_unit=angle_unit, robot=rob)
    res = calibrate(rob, ds, compliance=compliance)
    typer.echo(res.report())
    save_robot_toml(res.robot, out)
    typer.echo(f"calibrated robot written to {out}")


@app.command("register")
def register_cmd(
    model: str = typer.Argument(..., help="Model file trained on an earlier series."),
    series: Path = typer.Argument(..., help="New measurement series (.csv/.parquet)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output model file with re-fitted base and tool."),
    poses: int = typer.Option(30, "--poses", help="Number of poses of the series used to register (spread over it)."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Re-fit base and tool frames for a new series (tracker moved, tool changed); keep the learned errors."""
    from .dataset import read_dataset
    from .hybrid import HybridModel
    from .register import register_model

    mdl = HybridModel.load(str(model))
    ds = read_dataset(series, length_unit=length_unit, angle_unit=angle_unit, robot=mdl.robot)
    new, info = register_model(mdl, ds, n_poses=poses)
    new.save(out)
    typer.echo(info.summary())
    typer.echo(f"registered model written to {out}")


@app.command("export")
def export_cmd(
    model: str = typer.Argument(..., help="Model file."),
    out: Path = typer.Option(..., "-o", "--out", help="Output .onnx file."),
) -> None:
    """Export a hybrid model to ONNX (joints in, 4x4 poses out) and check it against PyTorch."""
    from .export import export_onnx
    from .hybrid import HybridModel

    mdl = HybridModel.load(model)
    info = export_onnx(mdl, out)
    typer.echo(f"wrote {out}; ONNX Runtime vs hykin max difference {info['max_pos_diff_mm']:.2e} mm, {info['max_ang_diff_deg']:.2e} deg")
    if "thermal_coefficient_per_k" in info:
        typer.echo(f"note: poses at the reference {info['thermal_reference_c']:.2f} °C; thermal expansion on the controller: "
                   f"p = b + (1 + {info['thermal_coefficient_per_k']:.4g} (t - {info['thermal_reference_c']:.2f})) (p - b), "
                   f"b = {[round(v, 6) for v in info['thermal_origin_m']]} m")


@app.command("demo")
def demo_cmd(
    out: Path = typer.Option(Path("hykin-demo"), "-o", "--out", help="Output directory for the report and files."),
    n_train: int = typer.Option(10_000, "--n-train", help="Training samples."),
    quick: bool = typer.Option(False, "--quick", help="A much smaller run (for smoke tests)."),
    seed: int = typer.Option(0, "--seed"),
) -> None:
    """The main job on the embedded default: virtual RX160, calibrate, train, evaluate, IK, report."""
    from .demo import run_demo

    path = run_demo(out, n_train=n_train, quick=quick, seed=seed)
    typer.echo(f"report: {path}")


# --------------------------------------------------------------------------- entry point


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: one-line errors, non-zero exit status."""
    import warnings

    # Warnings (e.g. queries outside the training region) as one readable line, no source echo.
    warnings.formatwarning = lambda message, category, *a, **k: f"hykin: warning: {message}\n"
    try:
        app(args=argv, prog_name="hykin")
    except SystemExit:
        raise
    except KeyboardInterrupt:
        print("hykin: interrupted", file=sys.stderr)
        sys.exit(130)
    except (CLIError, ValueError, OSError, KeyError, ImportError, RuntimeError) as e:
        msg = str(e).strip().splitlines()
        print(f"hykin: error: {msg[0] if msg else type(e).__name__}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
