"""``hykin report``: the model report (one self-contained HTML file) from a model and optional test data."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import AngleUnit, CLIError, Force, LengthUnit, app, check_report_dir, load_model_or_robot


@app.command("report")
def report_cmd(
    model: str = typer.Argument(..., metavar="MODEL", help="Model file (or a robot file / preset: classical model only)."),
    test: Path | None = typer.Argument(None, metavar="TEST", help="Test dataset (.csv/.parquet); without it the report "
                                       "shows the model card, calibration and the model's own held-out errors."),
    out: Path = typer.Option(..., "-o", "--out", help="Output directory; the report is DIR/report.html."),
    ik_targets: int = typer.Option(20, "--ik-targets", help="Targets for the warm hybrid-IK timing (count; 0 = no timing)."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
    force: bool = Force,
) -> None:
    """Write DIR/report.html: summary in words, model card, accuracy (per axis, per joint, in the workspace,
    ISO 9283), training support, calibration table and correlations, IK timings. One file, no external
    resources, prints on A4."""
    import warnings

    from ..evaluation.report_build import build_report, write_report
    from ..io.dataset_files import read_dataset

    if ik_targets < 0:
        raise CLIError(f"--ik-targets must be >= 0, got {ik_targets}")
    check_report_dir(out, (model, test), force)
    mdl, rob = load_model_or_robot(model)
    ds = None if test is None else read_dataset(test, length_unit=length_unit, angle_unit=angle_unit, robot=rob)
    with warnings.catch_warnings():
        from ..hybrid.model import OutOfRangeWarning

        # the report counts the test poses outside the training data itself
        warnings.simplefilter("ignore", OutOfRangeWarning)
        rep, res = build_report(mdl if mdl is not None else rob, ds, model_path=model if mdl is not None else None,
                                test_path=test, ik_targets=ik_targets)
    path = write_report(rep, out, res)
    typer.echo(f"report written to {path}")
