"""Data commands: presets, simulate, import, split."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import AngleUnit, CLIError, LengthUnit, app, progress

@app.command("presets")
def presets_cmd() -> None:
    """List the robot presets and the virtual-robot presets shipped with hykin."""
    from ..robot import list_presets, load_robot

    typer.echo("robot presets (use as ROBOT):")
    for name in list_presets():
        r = load_robot(name)
        typer.echo(f"  {name:16s} {r.dof} dof, {r.convention}")
    try:
        from ..simulate import list_virtual_presets, virtual_preset

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
    payloads: Optional[str] = typer.Option(None, "--payloads", help="Payload masses in kg, e.g. 0,12: rows cycle through them (column payload_kg)."),
) -> None:
    """Simulate a measured dataset from a virtual robot whose truth is known."""
    from ..simulate import simulate_to_file

    pl = None
    if payloads is not None:
        try:
            pl = [float(v) for v in payloads.split(",") if v.strip()]
        except ValueError:
            raise CLIError(f"--payloads: expected comma-separated masses in kg (e.g. 0,12), got {payloads!r}") from None
        if not pl or any(not (v >= 0 and v < float("inf")) for v in pl):
            raise CLIError(f"--payloads: masses must be finite and >= 0 kg, got {payloads!r}")

    with progress() as prog:
        task = prog.add_task(f"simulating {preset}", total=n)
        info = simulate_to_file(
            preset, n, out, plan=plan.replace("-", "_"), seed=seed, noise=noise, payloads=pl,
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
    from ..dataset import write_dataset
    from ..importers import import_ipa_series, import_ur5, ipa_nominal_robot, ur5_robot_for_dataset
    from ..robot import save_robot_toml

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
    from ..dataset import read_dataset, split, write_dataset

    ds = read_dataset(data, length_unit=length_unit, angle_unit=angle_unit)
    tr, te = split(ds, (1.0 - test, test), seed=seed, group=group)
    suffix = data.suffix if data.suffix in (".csv", ".parquet") else ".csv"
    paths = [Path(f"{out_prefix}_train{suffix}"), Path(f"{out_prefix}_test{suffix}")]
    write_dataset(tr, paths[0])
    write_dataset(te, paths[1])
    typer.echo(f"wrote {len(tr)} training rows to {paths[0]} and {len(te)} test rows to {paths[1]}")
