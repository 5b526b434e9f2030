"""Data commands: presets, simulate, split (imports: :mod:`hykin.cli.imports`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
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
            typer.echo(f"  {name:19s} {desc[0] if desc else ''} [nominal: {vr.nominal.name}, payload {vr.nominal.payload_kg:g} kg]")
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
    trajectory: Path | None = typer.Option(None, "--trajectory", help="With --stream: joint trajectory CSV (t_s and q1..qN, or q<i>_deg) from `hykin plan --trajectory`."),
    stream: bool = typer.Option(False, "--stream", help="Record the trajectory as a cell would: -o DIR gets robot_log.csv, tracker.csv and clock_truth.json."),
    robot_rate: float = typer.Option(100.0, "--robot-rate", help="Stream: controller log rate (Hz).", min=1.0),
    tracker_rate: float = typer.Option(1000.0, "--tracker-rate", help="Stream: tracker rate (Hz).", min=1.0),
    clock_offset_ms: float = typer.Option(12.3, "--clock-offset-ms", help="Stream: tracker clock minus robot clock (ms)."),
    latency_ms: float = typer.Option(2.0, "--latency-ms", help="Stream: tracker time-stamp latency (ms); adds to the offset."),
    drift_ppm: float = typer.Option(20.0, "--drift-ppm", help="Stream: tracker clock drift (ppm)."),
    beam_loss_speed: float = typer.Option(1.0, "--beam-loss-speed", help="Stream: the tracker loses the beam above this reflector speed (m/s).", min=0.0),
    dropouts_per_min: float = typer.Option(2.0, "--dropouts-per-min", help="Stream: random beam interruptions per minute (mean length 50 ms).", min=0.0),
    orientation: bool = typer.Option(False, "--orientation/--position-only", help="Stream: the tracker also measures orientation (6-D probe)."),
    force: bool = Force,
) -> None:
    """Simulate a measured dataset from a virtual robot whose truth is known (or, with --stream, the
    robot log and tracker stream of a dynamic collection along --trajectory)."""
    if stream or trajectory is not None:
        if not (stream and trajectory is not None):
            raise CLIError("simulate: --stream and --trajectory go together (record a trajectory as streams)")
        _simulate_stream(preset, trajectory, out, seed, noise, robot_rate, tracker_rate, clock_offset_ms * 1e-3,
                         latency_ms * 1e-3, drift_ppm * 1e-6, beam_loss_speed, dropouts_per_min, orientation, force)
        return
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


def _read_trajectory(path: Path, dof: int) -> tuple[np.ndarray, np.ndarray]:
    """``(t_s (T,), q (T, dof))`` from a trajectory CSV (``t_s`` and ``q1..qN`` rad or ``q<i>_deg``)."""
    from ..io.text_table import float_column, read_delimited

    t = read_delimited(path)
    if "t_s" not in t.header:
        raise CLIError(f"{path}: no t_s column (found {', '.join(t.header)}); write it with `hykin plan --trajectory -o TRAJ.csv`")
    cols = []
    for j in range(1, dof + 1):
        if f"q{j}" in t.header:
            cols.append(float_column(t, f"q{j}"))
        elif f"q{j}_deg" in t.header:
            cols.append(np.radians(float_column(t, f"q{j}_deg")))
        else:
            raise CLIError(f"{path}: missing joint column q{j} (or q{j}_deg) for a {dof}-joint robot")
    return float_column(t, "t_s"), np.stack(cols, axis=1)


def _simulate_stream(preset, trajectory, out: Path, seed, noise, robot_rate, tracker_rate, offset_s, latency_s, drift,
                     beam_loss_speed, dropouts_per_min, orientation, force) -> None:
    import json

    from ..io.csv_writer import write_csv
    from ..sim.presets import virtual_preset
    from ..sim.recording import record_cell
    from ..sim.simulate import SimulationError, load_truth, save_truth

    files = [out / "robot_log.csv", out / "tracker.csv", out / "clock_truth.json", out / "truth.json"]
    if out.exists() and not out.is_dir():
        raise CLIError(f"{out}: --stream writes a folder, and this is a file")
    if out.is_dir():
        for f in files:
            check_output(f, (preset, trajectory), force)
    elif not out.parent.is_dir():
        raise CLIError(f"{out}: its parent folder {out.parent} does not exist")
    vr = load_truth(preset) if preset.lower().endswith(".json") else virtual_preset(preset, seed=seed)
    t, q = _read_trajectory(trajectory, vr.truth.dof)
    with progress() as prog:
        task = prog.add_task("recording the cell", total=None)
        try:
            rec = record_cell(vr, t, q, robot_rate_hz=robot_rate, tracker_rate_hz=tracker_rate, offset_s=offset_s,
                              latency_s=latency_s, drift=drift, noise=noise, orientation=orientation,
                              beam_loss_speed_m_s=beam_loss_speed if beam_loss_speed > 0 else np.inf,
                              dropouts_per_min=dropouts_per_min, seed=seed,
                              progress=lambda d, n: prog.update(task, completed=d, total=n))
        except SimulationError as e:
            raise CLIError(f"{trajectory}: {e}") from None
    out.mkdir(parents=True, exist_ok=True)
    write_csv(files[0], {"t": rec.t_robot_s, **{f"q{j + 1}": rec.q_robot[:, j] for j in range(rec.q_robot.shape[1])}})
    cols = {"t": rec.t_tracker_s, "x": rec.p_tracker_m[:, 0], "y": rec.p_tracker_m[:, 1], "z": rec.p_tracker_m[:, 2]}
    if rec.quat_tracker is not None:
        cols.update({k: rec.quat_tracker[:, i] for i, k in enumerate(("qw", "qx", "qy", "qz"))})
    write_csv(files[1], cols)
    files[2].write_text(json.dumps(rec.truth, indent=2) + "\n", encoding="utf-8")
    save_truth(vr, files[3])
    tr = rec.truth
    typer.echo(f"wrote {tr['n_robot']} robot samples at {robot_rate:g} Hz and {tr['n_tracker']} tracker samples at "
               f"{tracker_rate:g} Hz to {out} ({tr['n_lost']} without beam: {tr['n_lost_fast']} too fast, "
               f"{tr['n_dropouts']} dropouts); clock truth: offset {tr['offset_s'] * 1e3:.3f} ms, drift {tr['drift'] * 1e6:g} ppm")


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
