"""Model commands: fit, calibrate, register, evaluate, export, demo."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from .common import (
    AngleUnit,
    BaseLink,
    CLIError,
    Force,
    LengthUnit,
    TipLink,
    UnitCheck,
    app,
    check_output,
    check_report_dir,
    console,
    load_model,
    load_model_or_robot,
    load_robot_spec,
)

OrientationWeight = typer.Option(
    "auto", "--orientation-weight",
    help="Weight of orientation residuals in the calibration, m/rad (1 mrad counts like w·1 mrad of length), "
         "or 'auto': sigma_pos / sigma_rot estimated from the data.")
MaxDeviation = typer.Option(
    None, "--max-deviation",
    help="Plausible calibration bounds, KIND=VALUE[,...]: length_mm (20), angle_deg (2), joint_offset_deg (5), "
         "deflection_deg (1), tool_m (2), residual_mm (3), residual_deg (1), orientation_conflict (3, x the positions-alone RMS).")


def _prior_help() -> str:
    from ..calibration.priors import PRIOR_HELP

    return PRIOR_HELP


Prior = typer.Option(None, "--prior", help=_prior_help())
Outliers = typer.Option(
    "drop", "--outliers",
    help="Poses far off the calibrated model (a lost beam, a wrong point name): drop (leave them out of the fit "
         "and name them), warn (name them only) or keep (no test).")
OutlierRatio = typer.Option(
    12.0, "--outlier-ratio",
    help="A pose is an outlier beyond this many typical errors (median-based, per coordinate) off the calibrated model.")


def _calibration_options(orientation_weight: str, max_deviation: str | None, prior: list[str] | None = None,
                         outliers: str = "drop", outlier_ratio: float = 12.0) -> dict:
    """``calibrate`` keyword arguments from the CLI options (CLIError on bad values)."""
    from ..hybrid.fit_options import calibration_options

    try:
        return calibration_options(orientation_weight, max_deviation, prior, outliers, outlier_ratio)
    except ValueError as e:
        raise CLIError(str(e)) from None


@app.command("fit")
def fit_cmd(
    robot: str = typer.Argument(..., help="Robot file (.toml), URDF, or preset name."),
    train: Path = typer.Argument(..., help="Training dataset (.csv/.parquet)."),
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    out: Path = typer.Option(..., "-o", "--out", help="Output model file (one safetensors file)."),
    val: Path | None = typer.Option(None, "--val", help="Validation dataset (default: 10% of TRAIN held out)."),
    arch: str = typer.Option("default", "--arch", help="Network architecture: default, D1, D4, D4w, D4W, Rw, Rd, B1..B4."),
    recipe: str = typer.Option("default", "--recipe", help="Training recipe: default or paper."),
    calibrate: bool = typer.Option(True, "--calibrate/--no-calibrate", help="Parametric calibration before the networks."),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda, or auto."),
    seed: int = typer.Option(0, "--seed", help="Random seed (validation split, network initialisation, batch order): "
                             "same data, options and seed give the same model."),
    max_minutes: float | None = typer.Option(None, "--max-minutes", help="Time budget for network training, minutes "
                                             "(training stops there, keeps the best weights and says how far it got)."),
    thermal: str = typer.Option("auto", "--thermal", help="Thermal expansion from a temperature_c column: auto, on, off."),
    min_steps: int | None = typer.Option(None, "--min-steps", help="Least number of optimiser steps per network (default recipe: 30000)."),
    max_epochs: int | None = typer.Option(None, "--max-epochs", help="Most training epochs per network (default: the recipe's)."),
    orientation_weight: str = OrientationWeight,
    max_deviation: str | None = MaxDeviation,
    prior: list[str] | None = Prior,
    outliers: str = Outliers,
    outlier_ratio: float = OutlierRatio,
    region_cv: bool = typer.Option(False, "--region-cv", help="Choose the calibration's parameter set by region-blocked validation."),
    fade_cv: int = typer.Option(0, "--fade-cv", help="Measure the fade by leave-one-region-out over this many regions (>= 2; 0 = fixed fade)."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
    unit_check: bool = UnitCheck,
    force: bool = Force,
) -> None:
    """Fit a hybrid model: calibrate the classical model, then train the residual networks.

    The same path as the Python API (HybridModel(robot).fit(train, val)). Without --val the model holds
    out 10 % of TRAIN for validation itself, so the same data, options and seed give the same model; the
    calibration uses all of TRAIN."""
    from ..hybrid.fit_options import model_kwargs
    from ..hybrid.model import HybridModel
    from ..io.dataset_files import read_dataset
    from ..io.plausibility import check_fit_size
    from .common import NOT_MODEL_SUFFIXES

    try:  # the one mapping of fit options to model settings (hykin.hybrid.fit_options, also used by sweeps)
        kw = model_kwargs(arch=arch, recipe=recipe, calibrate=calibrate, device=device, seed=seed,
                          max_minutes=max_minutes, thermal=thermal, min_steps=min_steps, max_epochs=max_epochs,
                          orientation_weight=orientation_weight, max_deviation=max_deviation, prior=prior,
                          region_cv=region_cv, fade_cv=fade_cv, outliers=outliers, outlier_ratio=outlier_ratio)
    except ValueError as e:
        raise CLIError(str(e)) from None
    check_output(out, (robot, train, val), force)  # before any long work
    if out.suffix.lower() in NOT_MODEL_SUFFIXES:  # fk, ik, evaluate ... would read it as a robot or data file
        raise CLIError(f"{out}: hykin fit writes a model file, which the other commands would read as a "
                       f"{out.suffix} robot or data file; name it .hykin ({out.with_suffix('.hykin').name})")
    rob = load_robot_spec(robot, base_link, tip_link)
    tr = read_dataset(train, length_unit=length_unit, angle_unit=angle_unit, robot=rob, unit_check=unit_check)
    check_fit_size(rob, tr)
    va = None
    if val is not None:
        va = read_dataset(val, length_unit=length_unit, angle_unit=angle_unit, robot=rob, unit_check=unit_check)
    model = HybridModel(rob, **kw)
    model.fit(tr, va, progress=True)
    model.save(out)
    if model.calibration_ is not None:
        typer.echo(model.calibration_.summary())
        for note in getattr(model.calibration_, "notes", []):
            console().print(f"note: {note}", highlight=False)
        for warn in getattr(model.calibration_, "coverage", []):  # a joint never moved, the tool at one orientation
            console().print(f"[yellow]warning:[/] {warn}", highlight=False)  # (print escapes [tool])
    if model.thermal_ is not None:
        typer.echo(f"thermal expansion: {model.thermal_.note} (reference {model.thermal_.reference_c:.2f} °C)")
    if model.fade_calibration_ is not None:
        typer.echo(model.fade_calibration_.summary())
    if model.calibration_cv_ is not None:
        typer.echo(model.calibration_cv_.table())
    _print_metrics(model)
    for name, m in model.metadata.get("metrics", {}).items():  # what the figures of unseen rows rest on
        if "n_rows" in m:
            typer.echo(f"{name}: {m['n_rows']} rows the networks were not trained on"
                       + (" (the calibration used them)" if name == "held_out" else ""))
    typer.echo(f"model written to {out}")


def _print_metrics(model) -> None:
    """One line per evaluated set: calibrated vs hybrid mean errors (mm, deg; 4 decimals, or 3 significant
    digits below 0.001, so noise-free virtual data do not read 0.0000)."""
    metrics = (getattr(model, "metadata", None) or {}).get("metrics") or {}
    f = lambda v: f"{v:.4f}" if not abs(v) < 1e-3 or v == 0 else f"{v:.3g}"
    for name, m in metrics.items():
        line = f"{name}: calibrated {f(m.get('classical_pos_mean_mm', float('nan')))} mm"
        if "classical_rot_mean_deg" in m:
            line += f" / {f(m['classical_rot_mean_deg'])} deg"
        line += f" -> hybrid {f(m.get('hybrid_pos_mean_mm', float('nan')))} mm"
        if "hybrid_rot_mean_deg" in m:
            line += f" / {f(m['hybrid_rot_mean_deg'])} deg"
        typer.echo(line + " (mean)")


@app.command("evaluate")
def evaluate_cmd(
    model: str = typer.Argument(..., help="Model file (or a robot: classical only)."),
    test: Path = typer.Argument(..., help="Test dataset (.csv/.parquet)."),
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    as_json: bool = typer.Option(False, "--json", help="Print the table as JSON."),
    report: Path | None = typer.Option(None, "--report", help="Write an HTML report with plots to this directory."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
    unit_check: bool = UnitCheck,
    fit_frames: bool = typer.Option(False, "--fit-frames", help="Fit base and tool of every row to the test poses "
                                    "(data in another frame than the model's: a moved tracker, another tool; the 12 "
                                    "fitted frame parameters flatter the figures). Without it such data are refused "
                                    "(register the model first)."),
    force: bool = Force,
) -> None:
    """Before/after error table (mean, std, p95, max; position mm, orientation deg)."""
    from ..evaluation.evaluate import FrameMismatchError, evaluate_model
    from ..evaluation.report_build import evaluation_report
    from ..io.dataset_files import read_dataset

    if report is not None:
        check_report_dir(report, (model, test), force)
    mdl, rob = load_model_or_robot(model, base_link, tip_link)
    ds = read_dataset(test, length_unit=length_unit, angle_unit=angle_unit, robot=rob, unit_check=unit_check)
    try:
        res = evaluate_model(mdl if mdl is not None else rob, ds, fit_frames=fit_frames)
    except FrameMismatchError as e:
        raise CLIError(f"{e} (or --fit-frames: every row with base and tool fitted to these poses)") from None
    if as_json:
        typer.echo(json.dumps(res.to_dict(), indent=2))
    else:
        typer.echo(res.table())
    if report is not None:
        import warnings

        from ..hybrid.model import OutOfRangeWarning

        with warnings.catch_warnings():  # the report counts the poses outside the training data itself
            warnings.simplefilter("ignore", OutOfRangeWarning)
            path = evaluation_report(res, report, model=mdl if mdl is not None else rob, data=ds,
                                     model_path=model if mdl is not None else None, test_path=test)
        typer.echo(f"report written to {path}")


@app.command("calibrate")
def calibrate_cmd(
    robot: str = typer.Argument(..., help="Robot file (.toml), URDF, or preset name."),
    data: Path = typer.Argument(..., help="Measured dataset (.csv/.parquet)."),
    out: Path = typer.Option(..., "-o", "--out", help="Calibrated robot file: .urdf (any robot; a URDF robot is written into its own URDF) or .toml (DH/MDH robots)."),
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    compliance: bool = typer.Option(True, "--compliance/--no-compliance", help="Identify joint compliance under gravity."),
    orientation_weight: str = OrientationWeight,
    max_deviation: str | None = MaxDeviation,
    prior: list[str] | None = Prior,
    outliers: str = Outliers,
    outlier_ratio: float = OutlierRatio,
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
    unit_check: bool = UnitCheck,
    force: bool = Force,
) -> None:
    """Parametric calibration only (geometry, base, tool, joint compliance); writes a robot file.

    The data may be in any frame (a tracker's) with an unknown tool offset: base and tool are found
    first. Every parameter has a prior (the robot file's value, a tolerance per kind: --prior); what the
    data do not excite is held there and reported so. A calibration that does not converge, puts a
    parameter beyond its tolerances (--prior refuse_tolerances, --max-deviation) or leaves an
    implausible residual is refused (exit 2, nothing written)."""
    from ..calibration.calibrate import calibrate
    from ..io.dataset_files import read_dataset

    check_output(out, (robot, data), force)
    rob = load_robot_spec(robot, base_link, tip_link)
    _check_robot_out(rob, out)
    ds = read_dataset(data, length_unit=length_unit, angle_unit=angle_unit, robot=rob, unit_check=unit_check)
    from ..calibration.thermal import temperature_of

    t = temperature_of(ds)  # checked (units) though unused here
    if t is not None and np.ptp(t) > 0:
        console().print(f"[yellow]note:[/] {data} has temperatures {t.min():.2f}-{t.max():.2f} °C: hykin calibrate fits no "
                        "thermal expansion (hykin fit does); the robot file is the fit over all of them", highlight=False)
    res = calibrate(rob, ds, compliance=compliance, **_calibration_options(orientation_weight, max_deviation, prior, outliers,
                                                                                  outlier_ratio))
    typer.echo(res.report())
    for note in res.notes:
        console().print(f"note: {note}", highlight=False)
    for warn in res.coverage:  # what the data did not cover: the file holds only where they were taken
        console().print(f"[yellow]warning:[/] {warn}", highlight=False)  # (print escapes [tool])
    _write_calibrated(res.robot, out, res.coverage)
    if res.station_frames is not None:  # several stations / tools: the file holds the reference's frames
        fr = res.station_frames
        parts = ([f"its [base] is station {fr.reference_station!r}'s frame"] if len(fr.station_labels) > 1 else []) + (
            [f"its [tool] is tool {fr.tool_labels[0]!r}'s"] if len(fr.tool_labels) > 1 else [])
        typer.echo(f"note: {' and '.join(parts)} (the reference: most rows); the others' frames are listed above")


def _check_robot_out(rob, out: Path) -> None:
    """Refuse, before calibrating, an output a robot cannot be written as (a URDF robot as TOML)."""
    if rob.convention == "urdf" and out.suffix.lower() != ".urdf":
        raise CLIError(f"{out}: a URDF robot is written as URDF; name the output {out.with_suffix('.urdf').name}")


def _with_comments(text: str, warnings: list[str], urdf: bool) -> str:
    """``text`` (a TOML or URDF robot file) with one comment line per calibration warning on top (after
    an XML declaration); readers ignore them, a person opening the file sees where it holds."""
    if not warnings:
        return text
    if not urdf:
        return "".join(f"# hykin calibrate warning: {w}\n" for w in warnings) + text
    lines = "".join(f"<!-- hykin calibrate warning: {w.replace('--', '- -')} -->\n" for w in warnings)
    head, sep, rest = text.partition("?>\n") if text.startswith("<?xml") else ("", "", text)
    return head + sep + lines + rest


def _write_calibrated(robot, out: Path, warnings: list[str] | None = None) -> None:
    """The calibrated robot as URDF (``.urdf``: the maker's URDF with calibrated joint origins, or any
    robot as a URDF chain) or else as a TOML robot file; ``warnings`` (what the data did not cover)
    go on top as comments."""
    if out.suffix.lower() == ".urdf":
        from ..io.urdf import calibrated_robot_urdf

        text, left = calibrated_robot_urdf(robot)
        out.write_text(_with_comments(text, warnings or [], urdf=True), encoding="utf-8")
        typer.echo(f"calibrated robot written to {out}" + (f" (a URDF cannot carry {left}: not written)" if left else ""))
        return
    from ..io.robot_toml import robot_to_toml_string

    out.write_text(_with_comments(robot_to_toml_string(robot), warnings or [], urdf=False), encoding="utf-8")
    typer.echo(f"calibrated robot written to {out}")


@app.command("register")
def register_cmd(
    model: str = typer.Argument(..., help="Model file trained on an earlier series, or a robot file (e.g. written by "
                                           "`hykin calibrate`), URDF or preset."),
    series: Path = typer.Argument(..., help="New measurement series (.csv/.parquet)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output model file (for a robot input: a robot file, .toml or .urdf)."),
    poses: int = typer.Option(30, "--poses", help="Number of poses of the series used to register (spread over it)."),
    frames_only: bool = typer.Option(False, "--frames-only", help="Re-fit base and tool only (no joint zeros / thermal state)."),
    orientation_weight: str = typer.Option(
        "auto", "--orientation-weight",
        help="Weight of orientation residuals in the registration, m/rad, or 'auto': sigma_pos / sigma_rot of a "
             "first fit on the registration poses."),
    alpha: float = typer.Option(1e-3, "--alpha", help="Significance of the consistency test (chi-square of the residuals "
                                                       "normalised by noise and the model's bands); 0 never refuses."),
    tolerance: float = typer.Option(3.0, "--tolerance", help="Factor on the expected error scale the test allows."),
    noise_mm: float = typer.Option(0.05, "--noise-mm", help="Measurement noise per coordinate, mm (orientation: "
                                                             "0.005 deg), added to the model's uncertainty."),
    nominal_check: str = typer.Option("pose", "--nominal-check",
                                      help="Fall back to the nominal model + frames when it predicts the registration poses "
                                           "better (leave-one-pose-out): pose (worse in position or orientation), "
                                           "position (position only) or off."),
    outliers: str = Outliers,
    outlier_ratio: float = OutlierRatio,
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
    unit_check: bool = UnitCheck,
    force: bool = Force,
) -> None:
    """Re-fit base and tool frames for a new series (tracker moved, tool changed) and, where the poses
    identify them and they are significant, joint zero offsets and a thermal state; keep the learned errors.
    Refuses (exit 2, one line) when a chi-square test shows the series does not fit the model; falls
    back to the nominal model with fitted frames where that predicts the series better."""
    from ..io.dataset_files import read_dataset
    from ..measure.register import register_model

    check_output(out, (model, series), force)
    if nominal_check not in ("pose", "position", "off"):
        raise CLIError(f"--nominal-check must be pose, position or off, got {nominal_check!r}")
    if not (0.0 <= alpha < 1.0) or not tolerance > 0 or not noise_mm >= 0:
        raise CLIError(f"--alpha must be in [0, 1), --tolerance > 0, --noise-mm >= 0 (got {alpha}, {tolerance}, {noise_mm})")
    o = _calibration_options(orientation_weight, None, None, outliers, outlier_ratio)
    w = o.get("orientation_weight_m_per_rad", "auto")
    mdl, rob = load_model_or_robot(model, base_link, tip_link)
    if mdl is None:
        from ..measure.robot_model import RobotModel

        if rob.convention not in ("dh", "mdh") and out.suffix.lower() != ".urdf":
            raise CLIError(f"{out}: a registered {rob.convention} robot is written as URDF: name the output .urdf")
        mdl = RobotModel(rob)
    ds = read_dataset(series, length_unit=length_unit, angle_unit=angle_unit, robot=rob, unit_check=unit_check)
    new, info = register_model(mdl, ds, n_poses=poses, refit="frames" if frames_only else "auto", orientation_weight=w,
                               alpha=alpha, tolerance=tolerance, noise_mm=noise_mm,
                               check_nominal=False if nominal_check == "off" else nominal_check,
                               outliers=o.get("outliers", "drop"), outlier_ratio=o.get("outlier_ratio", 12.0))
    if hasattr(new, "to_robot") and out.suffix.lower() == ".urdf":
        from ..io.urdf import robot_to_urdf

        out.write_text(robot_to_urdf(new.to_robot()), encoding="utf-8")
    elif hasattr(new, "to_robot"):
        from ..io.robot_toml import save_robot_toml

        save_robot_toml(new.to_robot(), out)
    else:
        new.save(out)
    typer.echo(info.report(robot=getattr(mdl, "robot_", None)))
    if not ds.has_orientation:  # positions show the tool's position and the base, never the tool's rotation
        console().print(f"[yellow]warning:[/] {series} has no orientation columns: the tool's orientation was not "
                        "registered; the written file's orientations keep the previous tool's (register a series "
                        "with orientation if the tool was changed or remounted)", highlight=False)
    typer.echo(f"registered {'robot' if hasattr(new, 'to_robot') else 'model'} written to {out}")


@app.command("export")
def export_cmd(
    model: str = typer.Argument(..., help="Model file."),
    out: Path = typer.Option(..., "-o", "--out", help="Output .onnx file."),
    force: bool = Force,
) -> None:
    """Export a hybrid model to ONNX (joints in, 4x4 poses out) and check it against hykin with ONNX Runtime.

    Inputs: q (N, dof) rad. A model whose poses depend on the payload (joint compliance, or trained on
    several payloads) also takes payload_kg ((N,) or (1,) kg) and, with joint compliance, payload_com_m
    ((N, 3) or (1, 3) m, tool frame; zeros: at the TCP); the check covers 0 kg, the trained payloads, the
    robot file's and one beyond. Output: pose (N, 4, 4) m. The output must end in .onnx."""
    from ..hybrid.export import export_onnx

    check_output(out, (model,), force)
    if out.suffix.lower() != ".onnx":
        raise CLIError(f"{out}: hykin export writes an ONNX graph; name the output {out.with_suffix('.onnx').name}")
    mdl = load_model(model)
    info = export_onnx(mdl, out)
    typer.echo(f"wrote {out}; ONNX Runtime vs hykin max difference {info['max_pos_diff_mm']:.2e} mm, {info['max_ang_diff_deg']:.2e} deg"
               + (f" at payloads {', '.join(f'{v:g}' for v in info['payloads_checked_kg'])} kg"
                  if info["payloads_checked_kg"] else ""))
    if len(info["inputs"]) > 1:
        com = " and payload_com_m ((N, 3) or (1, 3) m, tool frame; zeros: at the TCP)" if "payload_com_m" in info["inputs"] else ""
        typer.echo(f"note: the graph's inputs are q ((N, {mdl.robot.dof}) rad), payload_kg ((N,) or (1,) kg){com}: "
                   f"feed the payload the robot carries (the robot file's is {info['payload_default_kg']:g} kg)")
    if "thermal_coefficient_per_k" in info:
        typer.echo(f"note: poses at the reference {info['thermal_reference_c']:.2f} °C; thermal expansion on the controller: "
                   f"p = b + (1 + {info['thermal_coefficient_per_k']:.4g} (t - {info['thermal_reference_c']:.2f})) (p - b), "
                   f"b = {[round(v, 6) for v in info['thermal_origin_m']]} m")


@app.command("demo")
def demo_cmd(
    out: Path = typer.Option(Path("hykin-demo"), "-o", "--out", help="Output directory for the report and files."),
    n_train: int = typer.Option(10_000, "--n-train", help="Training samples."),
    quick: bool = typer.Option(False, "--quick", help="A much smaller run (for smoke tests)."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the simulated data and of the fits."),
    force: bool = Force,
) -> None:
    """The main job on the embedded default: virtual RX160, calibrate, train, evaluate, IK, report."""
    from .demo import run_demo

    check_report_dir(out, (), force)

    path = run_demo(out, n_train=n_train, quick=quick, seed=seed)
    typer.echo(f"report: {path}")


# --------------------------------------------------------------------------- entry point
