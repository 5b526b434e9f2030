"""Commands that run many fits on Ray: sweep (trials on Ray actors), fleet (one Ray task per robot)."""

from __future__ import annotations

import contextlib
from pathlib import Path

import typer

from .common import CLIError, app, check_output, mark_interrupt_said, plain_markup

Address = typer.Option(None, "--address", help="Ray cluster to join (e.g. auto, or ray://HEAD:10001); default: a local Ray on this machine's CPUs.")
NumCpus = typer.Option(None, "--num-cpus", help="CPUs of the local Ray (default: all of this machine's); ignored with --address.")


def _check_outputs(out: Path, names, inputs) -> None:
    """Refuse (one line, before Ray starts) an output file in ``out`` that is one of the run's input files
    (:func:`hykin.cli.common.check_output`, the rule of every command; an existing output is left to the
    earlier-run rule of --resume / --force)."""
    if not out.is_dir():
        return  # a folder to be made holds no input
    for name in names:
        check_output(out / name, inputs, force=True)


@app.command("sweep")
def sweep_cmd(
    sweep_file: Path = typer.Argument(..., help=plain_markup("Sweep file (.toml): robot, train, test, length_unit, angle_unit, [grid], [random], [resources].")),
    out: Path = typer.Option(..., "-o", "--out", help="Output directory: results.csv, error_vs_n_train.png."),
    address: str | None = Address,
    resume: bool = typer.Option(False, "--resume", help="Keep the finished trials in OUT; run only the others."),
    num_cpus: int | None = NumCpus,
    force: bool = typer.Option(False, "--force", help="Start over in an OUT that holds an earlier sweep (its "
                               "records are dropped); without it, or --resume, such an OUT is refused."),
) -> None:
    """Run every trial of a sweep file (each: `hykin fit` with its options + evaluation on the test set)
    on Ray (local, or a cluster with --address). A failing trial is retried once, then recorded with its error; exit 1 if any failed."""
    from ..distributed.sweep import SWEEP_OUTPUTS, run_sweep
    from ..distributed.sweep_file import read_sweep

    if out.exists() and not out.is_dir():
        raise CLIError(f"{out}: -o must name a directory, got an existing file")
    spec = read_sweep(sweep_file)
    _check_outputs(out, SWEEP_OUTPUTS,
                   (sweep_file, spec.robot, spec.train, spec.test))
    with _interrupted("sweep", sweep_file, out):
        res = run_sweep(spec, out, address=address, resume=resume, num_cpus=num_cpus, log=typer.echo, force=force)
    typer.echo(f"sweep: {len(res.rows) - len(res.failed)} of {len(res.rows)} trials ok ({res.ran} run now); "
               f"results in {res.results_csv}" + (f", plot {res.plot}" if res.plot else ""))
    _fail_lines([(f"trial {r['trial']}", r["error"] or r["status"]) for r in res.failed])


@app.command("fleet")
def fleet_cmd(
    fleet_file: Path = typer.Argument(..., help=plain_markup("Fleet file (.toml): one [[robot]] entry per robot (name, robot, train, test, register, "
                                                          "length_unit, angle_unit, [robot.fit]).")),
    out: Path = typer.Option(..., "-o", "--out", help="Output directory: NAME.hykin models, summary.csv, summary.md."),
    address: str | None = Address,
    num_cpus: int | None = NumCpus,
    resume: bool = typer.Option(False, "--resume", help="Keep the robots of OUT's summary.csv that are ok, have "
                                "their model files and unchanged inputs (hashes); run only the others."),
    force: bool = typer.Option(False, "--force", help="Fit every robot again in an OUT that holds an earlier fleet, "
                               "overwriting its models and summary; without it, or --resume, such an OUT is refused."),
) -> None:
    """Fit, evaluate and register every robot of a fleet file in parallel on Ray. A failing robot does
    not stop the others; exit 1 with one line per failed robot."""
    from ..distributed.fleet import fleet_outputs, run_fleet
    from ..distributed.fleet_file import read_fleet

    if out.exists() and not out.is_dir():
        raise CLIError(f"{out}: -o must name a directory, got an existing file")
    spec = read_fleet(fleet_file)
    _check_outputs(out, fleet_outputs(spec), [fleet_file] + [p for r in spec.robots
                                                            for p in (r.robot, r.train, r.test, r.register)])
    with _interrupted("fleet", fleet_file, out):
        rows = run_fleet(spec, out, address=address, num_cpus=num_cpus, log=typer.echo, resume=resume, force=force)
    ok = sum(r["status"] == "ok" for r in rows)
    typer.echo(f"fleet: {ok} of {len(rows)} robots ok; summary in {out / 'summary.csv'} and {out / 'summary.md'}")
    _fail_lines([(f"robot {r['name']}", r["error"]) for r in rows if r["status"] != "ok"])


@contextlib.contextmanager
def _interrupted(command: str, spec_file: Path, out: Path):
    """Ctrl-C in the block: one line on stderr (interrupted; what finished is kept in ``out``; ``--resume``
    continues) and exit status 130 (Typer otherwise ends a KeyboardInterrupt with 130 and no word)."""
    try:
        yield
    except KeyboardInterrupt:
        typer.echo(f"hykin: {command} interrupted; what finished is kept in {out}: `hykin {command} {spec_file} "
                   f"-o {out} --resume` continues", err=True)
        mark_interrupt_said()
        raise typer.Exit(130) from None


def _fail_lines(failed: list) -> None:
    """One line per failure on stderr and exit status 1 when there is any."""
    if failed:
        for what, err in failed:
            typer.echo(f"hykin: error: {what} failed: {err}", err=True)
        raise typer.Exit(1)
