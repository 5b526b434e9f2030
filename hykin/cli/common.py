"""Shared pieces of the command line: the Typer app, user-facing errors, console output, and the
loaders every command uses (model file or robot, CSV rows).

Commands live in the sibling modules, one module per family; each registers on :data:`app`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="hykin: high-accuracy hybrid kinematics for serial robot arms (classical model + calibration + residual networks).",
)

def _version(value: bool) -> None:
    if value:
        from .. import __version__

        typer.echo(f"hykin {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
) -> None:
    """hykin: high-accuracy hybrid kinematics for serial robot arms."""


LengthUnit = typer.Option("m", "--length-unit", help="Unit of x,y,z in the input files: m or mm.")
AngleUnit = typer.Option("rad", "--angle-unit", help="Unit of joint columns in the input files: rad or deg.")


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def console():
    from rich.console import Console

    return Console(stderr=True)


def progress():
    """A rich progress bar writing to stderr (disabled when stderr is not a terminal and CI is set)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console(),
        transient=False,
    )


def is_model_file(spec: str) -> bool:
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


def load_model_or_robot(spec: str):
    """Return ``(model_or_None, robot)`` for a model file, a robot file or a preset name."""
    from ..robot import load_robot

    if is_model_file(spec):
        from ..hybrid import HybridModel

        model = HybridModel.load(spec)
        return model, model.robot
    return None, load_robot(spec)


# --------------------------------------------------------------------------- commands


def temperature_of(mdl, extra: dict, path) -> np.ndarray | None:
    """The file's temperature column for a model with a thermal coefficient (note when it is missing)."""
    from ..thermal import temperature_from

    th = getattr(mdl, "thermal_", None)
    if th is None or th.coefficient_per_k == 0.0:
        return None
    t = temperature_from(extra, str(path))
    if t is None:
        console().print(f"[yellow]note:[/] the model compensates thermal expansion ({th.coefficient_per_k * 1e6:.2f} µm/m/K) "
                         f"but {path} has no temperature_c column: results at the reference {th.reference_c:.2f} °C")
    return t


def write_rows(rows: dict, out: Path) -> None:
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
