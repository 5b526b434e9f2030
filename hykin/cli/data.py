"""Data commands: presets, simulate, split (imports: :mod:`hykin.cli.imports`)."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import AngleUnit, CLIError, Force, LengthUnit, app, check_output, progress


@app.command("presets")
def presets_cmd() -> None:
    """List the robot presets and the virtual-robot presets shipped with hykin."""
    from ..io.robot_file import list_presets, load_robot

    typer.echo("robot presets (use as ROBOT):")
    for name in list_presets():
        r = load_robot(name)
        typer.echo(f"  {name:16s} {r.dof} dof, {r.convention}")
    try:
        from ..sim.presets import list_virtual_presets, virtual_preset

        typer.echo("virtual robots (use with `hykin simulate`; it writes the nominal robot to fit with, "
                   "NAME.nominal.toml, beside the data):")
        for name in list_virtual_presets():
            vr = virtual_preset(name)
            desc = (vr.description or "").strip().splitlines()
            typer.echo(f"  {name:16s} {desc[0] if desc else ''} [nominal: {vr.nominal.name}, payload {vr.nominal.payload_kg:g} kg]")
    except ImportError:  # pragma: no cover
        pass


@app.command("simulate")
def simulate_cmd(
    preset: str = typer.Argument(..., help="Virtual robot preset, e.g. rx160-virtual (see `hykin presets`)."),
    n: int = typer.Option(10_000, "-n", help="Number of samples.", min=1),
    out: Path = typer.Option(..., "-o", "--out", help="Output dataset (.csv or .parquet); the truth (NAME.truth.json) and "
                             "the nominal robot to fit with (NAME.nominal.toml) are written beside it."),
    seed: int = typer.Option(0, "--seed", help="Seed of the virtual robot's deviations, the poses and the noise (same "
                             "seed, same files). For more data from the SAME robot, pass its truth file (NAME.truth.json) "
                             "as PRESET: the seed then draws only poses and noise."),
    plan: str = typer.Option("uniform", "--plan", help="Sampling plan: uniform, random, zigzag, iso-cube, restricted."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Add tracker-like measurement noise."),
    payloads: str | None = typer.Option(None, "--payloads", help="Payload masses in kg, e.g. 0,12: rows cycle through them (column payload_kg)."),
    force: bool = Force,
) -> None:
    """Simulate a measured dataset from a virtual robot whose truth is known."""
    from ..sim.generate import simulate_to_file
    from ..sim.presets import virtual_preset
    from ..sim.simulate import load_truth, truth_path_for

    nominal_path = out.with_name(out.stem + ".nominal.toml")  # the robot to fit with: hykin fit NOMINAL OUT
    check_output(out, (preset,), force)
    check_output(truth_path_for(out), (preset,), force)  # the truth file written beside it
    check_output(nominal_path, (preset,), force)
    if preset.lower().endswith(".json"):
        vr = load_truth(preset)
    else:
        vr = virtual_preset(preset, seed=seed)  # an unknown name fails here, before the progress bar starts

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
    from ..io.robot_toml import save_robot_toml

    save_robot_toml(vr.nominal, nominal_path)
    typer.echo(f"wrote {n} samples to {out}" + (f" (truth: {info})" if info else ""))
    typer.echo(f"nominal robot of {vr.name} (payload {vr.nominal.payload_kg:g} kg): {nominal_path} "
               f"(fit with: hykin fit {nominal_path} {out} -o model.hykin)")


@app.command("split")
def split_cmd(
    data: Path = typer.Argument(..., help="Dataset to split (.csv/.parquet)."),
    out_prefix: Path = typer.Option(..., "-o", "--out", help="Output prefix: writes PREFIX_train.csv and PREFIX_test.csv."),
    test: float = typer.Option(0.2, "--test", help="Fraction held out for testing.", min=0.01, max=0.99),
    seed: int = typer.Option(0, "--seed", help="Random seed of the split (reproducible)."),
    group: str | None = typer.Option(None, "--group", help="Keep rows with the same value of this column together."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
    force: bool = Force,
) -> None:
    """Random train/test split of a dataset (disjoint, reproducible)."""
    from ..io.dataset import split
    from ..io.dataset_files import read_dataset, write_dataset

    suffix = data.suffix if data.suffix in (".csv", ".parquet") else ".csv"
    paths = [Path(f"{out_prefix}_train{suffix}"), Path(f"{out_prefix}_test{suffix}")]
    for p in paths:
        check_output(p, (data,), force)
    ds = read_dataset(data, length_unit=length_unit, angle_unit=angle_unit)
    tr, te = split(ds, (1.0 - test, test), seed=seed, group=group)
    write_dataset(tr, paths[0])
    write_dataset(te, paths[1])
    typer.echo(f"wrote {len(tr)} training rows to {paths[0]} and {len(te)} test rows to {paths[1]}")
