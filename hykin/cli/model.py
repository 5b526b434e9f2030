"""Model commands: fit, calibrate, register, evaluate, export, demo."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from .common import AngleUnit, CLIError, LengthUnit, app, load_model_or_robot

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
    region_cv: bool = typer.Option(False, "--region-cv", help="Choose the calibration's parameter set by region-blocked validation."),
    fade_cv: int = typer.Option(0, "--fade-cv", help="Measure the fade by leave-one-region-out over this many regions (>= 2; 0 = fixed fade)."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Fit a hybrid model: calibrate the classical model, then train the residual networks."""
    from ..dataset import read_dataset, split
    from ..hybrid import HybridModel
    from ..robot import load_robot

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
    if fade_cv == 1 or fade_cv < 0:
        raise CLIError(f"--fade-cv must be 0 (off) or >= 2 regions, got {fade_cv}")
    if region_cv:
        kw["calibrate_kw"] = {"select": "region-cv"}
    model = HybridModel(rob, arch=arch, recipe=recipe, calibrate=calibrate, device=device, seed=seed,
                        thermal=modes[thermal], fade_cv=fade_cv, **kw)
    model.fit(tr, va, progress=True)
    model.save(out)
    if model.thermal_ is not None:
        typer.echo(f"thermal expansion: {model.thermal_.note} (reference {model.thermal_.reference_c:.2f} °C)")
    if model.fade_calibration_ is not None:
        typer.echo(model.fade_calibration_.summary())
    if model.calibration_cv_ is not None:
        typer.echo(model.calibration_cv_.table())
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
    from ..dataset import read_dataset
    from ..evaluate import evaluate_model, evaluation_report

    mdl, rob = load_model_or_robot(model)
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
    from ..calibrate import calibrate
    from ..dataset import read_dataset
    from ..robot import load_robot, save_robot_toml

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
    frames_only: bool = typer.Option(False, "--frames-only", help="Re-fit base and tool only (no joint zeros / thermal state)."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Re-fit base and tool frames for a new series (tracker moved, tool changed) and, where the poses
    identify them and they are significant, joint zero offsets and a thermal state; keep the learned errors.
    Refuses (exit 2, one line) when the residual shows the series does not fit the model."""
    from ..dataset import read_dataset
    from ..hybrid import HybridModel
    from ..register import register_model

    mdl = HybridModel.load(str(model))
    ds = read_dataset(series, length_unit=length_unit, angle_unit=angle_unit, robot=mdl.robot)
    new, info = register_model(mdl, ds, n_poses=poses, refit="frames" if frames_only else "auto")
    new.save(out)
    typer.echo(info.report())
    typer.echo(f"registered model written to {out}")


@app.command("export")
def export_cmd(
    model: str = typer.Argument(..., help="Model file."),
    out: Path = typer.Option(..., "-o", "--out", help="Output .onnx file."),
) -> None:
    """Export a hybrid model to ONNX (joints in, 4x4 poses out) and check it against PyTorch."""
    from ..export import export_onnx
    from ..hybrid import HybridModel

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
    from ..demo import run_demo

    path = run_demo(out, n_train=n_train, quick=quick, seed=seed)
    typer.echo(f"report: {path}")


# --------------------------------------------------------------------------- entry point
