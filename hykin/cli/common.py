"""Shared pieces of the command line: the Typer app, user-facing errors, console output, and the
loaders every command uses (model file or robot, CSV rows).

Commands live in the sibling modules, one module per family; each registers on :data:`app`.
"""

from __future__ import annotations

import re

from pathlib import Path

import numpy as np
import typer

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="hykin: high-accuracy hybrid kinematics for serial robot arms (classical model + calibration + residual networks).",
)

def _plain_help() -> None:
    """Help as the README writes it: arguments upper-case (``ROBOT``, ``[TEST]``, not ``{robot}``), no
    ``<bool>`` type placeholder on flags, and value types as a user reads them (``<str>`` for a
    repeatable option, not ``<list[str]>``; ``<int> [x>=1]``, not ``<int range> [x>=1]``). Typer
    renders these itself; this adjusts its hooks: ``display_type_rich`` and ``_usage_display_name``
    from typer 0.29, ``make_metavar`` before (0.27 and 0.28 print ``{robot}`` and ``<int range>``
    otherwise; older releases already print them plainly)."""
    import re
    from typer import core as tc

    def plain_type(t):
        if not isinstance(t, str):
            return t
        return re.sub(r"<list\[(\w+)\]>", lambda m: f"<{m.group(1).lower()}>", t.replace(" range>", ">"))

    def usage_name(self):
        name = self.metavar or (self.name or "").upper()
        if not self.required and not name.startswith("["):
            name = f"[{name}]"
        return name + ("..." if self.nargs != 1 else "")

    opt_type = getattr(tc.TyperOption, "display_type_rich", None)
    if opt_type is not None and not getattr(opt_type, "_hykin", False):
        def display_type_rich(self, ctx):
            return None if getattr(self, "is_flag", False) else plain_type(opt_type(self, ctx))

        display_type_rich._hykin = True
        tc.TyperOption.display_type_rich = display_type_rich
    elif opt_type is None and not getattr(tc.TyperOption.make_metavar, "_hykin", False):
        opt_metavar = tc.TyperOption.make_metavar

        def option_metavar(self, *args, **kwargs):
            return plain_type(opt_metavar(self, *args, **kwargs))

        option_metavar._hykin = True
        tc.TyperOption.make_metavar = option_metavar
    if hasattr(tc.TyperArgument, "_usage_display_name"):
        tc.TyperArgument._usage_display_name = usage_name
        tc.TyperArgument.display_name_raw = property(lambda self: self.metavar or (self.name or "").upper())
    elif not getattr(tc.TyperArgument.make_metavar, "_hykin", False):
        import inspect

        arg_metavar = tc.TyperArgument.make_metavar
        if "usage" in inspect.signature(arg_metavar).parameters:
            def argument_metavar(self, *args, usage=False, **kwargs):
                return usage_name(self) if usage else arg_metavar(self, *args, usage=usage, **kwargs)

            argument_metavar._hykin = True
            tc.TyperArgument.make_metavar = argument_metavar


_plain_help()


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


UnitCheck = typer.Option(
    True, "--unit-check/--no-unit-check",
    help="Refuse data that look like another unit (mm read as m, rad read as deg; judged against the robot's reach "
         "and motion, not absolute coordinates). --no-unit-check when the values are right.")


Force = typer.Option(False, "--force", help="Overwrite the output file if it exists.")
BaseLink = typer.Option(None, "--base", metavar="LINK",
                        help="URDF robot: the chain's base link (default: the root link).")
TipLink = typer.Option(None, "--tip", metavar="LINK",
                       help="URDF robot: the chain's tip link (needed when the URDF has several tips).")


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def check_output(out, inputs=(), force: bool = False, directory: bool = False) -> Path:
    """Refuse a bad output path before any work is done; returns ``out`` as a Path.

    Refused: ``out`` naming any of ``inputs`` (symlinks and ``..`` resolved; a preset name or other
    non-path input is skipped), an existing output without ``force``, an output folder that does not
    exist or is not writable, and (``directory=False``) an existing directory as output file. Every
    command calls this first, so a typo in ``-o`` costs nothing and never overwrites measured data.
    """
    import os

    out = Path(out)
    target = out.resolve()
    for spec in inputs:
        if spec is None:
            continue
        p = Path(spec)
        if not p.exists():
            continue
        same = p.resolve() == target
        if not same and out.exists():
            try:
                same = os.path.samefile(p, out)
            except OSError:
                same = False
        if same:
            raise CLIError(f"{out}: refusing to write the output over the input file {spec} (choose another -o)")
    if out.is_dir() and not directory:
        raise CLIError(f"{out}: is a directory; expected an output file name")
    if out.exists() and not force and not (directory and out.is_dir() and not any(out.iterdir())):
        raise CLIError(f"{out}: output exists; pass --force to overwrite it")
    folder = target.parent
    if not folder.is_dir():
        raise CLIError(f"{out}: output folder {folder} does not exist (create it first)")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise CLIError(f"{out}: output folder {folder} is not writable")
    return out


#: the rich style tags hykin's messages use; any other ``[...]`` in a message is text (``[tool]``, ``[mm]``)
_STYLE_TAG = re.compile(r"\\\[(/?(?:yellow|red|green|bold|dim|cyan)?)\]")


def plain_markup(text: str) -> str:
    """``text`` with every ``[...]`` escaped for rich except hykin's own style tags: rich drops unknown
    tags, so "the robot file's [tool]" printed as "the robot file's " and "[mm]" vanished from headers."""
    from rich.markup import escape

    return _STYLE_TAG.sub(lambda m: f"[{m.group(1)}]", escape(text))


def check_report_dir(out, inputs=(), force: bool = False) -> Path:
    """:func:`check_output` for a report directory ``out`` (DIR/report.html): an existing file there, or a
    ``report.html`` already in it, is refused without ``force``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"{out}: must name a directory, got an existing file")
    check_output(out, inputs, force=True, directory=True)
    if (out / "report.html").exists() and not force:
        raise CLIError(f"{out / 'report.html'}: output exists; pass --force to overwrite it")
    return out


def console():
    from rich.console import Console

    class _Console(Console):
        def print(self, *objects, **kw):  # noqa: A003 - rich's name
            if kw.get("markup") is False:  # printed as it is: escaping would show its backslashes ("\[tool]")
                return super().print(*objects, **kw)
            super().print(*(plain_markup(o) if isinstance(o, str) else o for o in objects), **kw)

    # soft wrap: a message stays one line in logs and pipes (rich otherwise breaks it at 80 columns
    # when the output is not a terminal); tables still fit the width
    return _Console(stderr=True, soft_wrap=True)


class _LogProgress:
    """The :func:`progress` interface (``add_task`` / ``update``) as plain log lines (stderr not a
    terminal): a line per task when it starts and ends, and one at least every 10 s with an ETA."""

    def __init__(self):
        self.tasks = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        for log, _ in self.tasks.values():
            log.done()

    def add_task(self, description: str, total=None, **_):
        from ..hybrid.progress import LogLines

        k = len(self.tasks)
        self.tasks[k] = (LogLines(description, unit="samples"), [0, total])
        return k

    def update(self, task, completed=None, total=None, **_):
        log, st = self.tasks[task]
        st[0] = st[0] if completed is None else completed
        st[1] = st[1] if total is None else total
        log.update(int(st[0]), st[1])


def progress():
    """A rich progress bar writing to stderr on a terminal; plain log lines otherwise (:class:`_LogProgress`)."""
    import sys

    if not sys.stderr.isatty():
        return _LogProgress()
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console(),
        transient=False,
    )


#: suffixes the commands read as robot or data files whatever the content: a model is never named so
NOT_MODEL_SUFFIXES = (".toml", ".urdf", ".csv")


def is_model_file(spec: str) -> bool:
    """Whether ``spec`` is a hykin model file: a safetensors file (by content) not named as a robot or data
    file (:data:`NOT_MODEL_SUFFIXES`)."""
    p = Path(spec)
    if not p.is_file():
        return False
    with open(p, "rb") as f:
        head = f.read(8)
    # safetensors files start with an 8-byte little-endian header length followed by '{'
    if len(head) < 8:
        return False
    n = int.from_bytes(head, "little")
    return 0 < n < 100_000_000 and p.suffix.lower() not in NOT_MODEL_SUFFIXES


def load_model_or_robot(spec: str, base: str | None = None, tip: str | None = None):
    """Return ``(model_or_None, robot)`` for a model file, a robot file or a preset name; ``base`` /
    ``tip`` (``--base``/``--tip``): the chain of a URDF file. A model file keeps the chain it was
    fitted on; naming other links for it is refused."""
    if is_model_file(spec):
        from ..hybrid.model import HybridModel

        model = HybridModel.load(spec)
        _check_links(spec, model.robot, base, tip)
        return model, model.robot
    p = Path(spec)
    if p.is_file() and p.suffix.lower() not in (".toml", ".urdf"):
        from ..io.modelfile import looks_like_model_file

        if looks_like_model_file(p):  # a model renamed .csv: is_model_file goes by the name for these suffixes
            raise CLIError(f"{spec}: this is a hykin model file named {p.suffix}, which names a data file: rename it .hykin")
        raise CLIError(f"{spec}: not a hykin model file, robot file (.toml/.urdf) or preset name")
    return None, load_robot_spec(spec, base, tip)


def load_robot_spec(spec, base: str | None = None, tip: str | None = None):
    """A robot file, URDF (chain ``--base`` -> ``--tip``) or preset; the one robot loader of the CLI."""
    from ..io.robot_file import load_robot

    return load_robot(spec, base_link=base, tip_link=tip)


def _check_links(spec, robot, base: str | None, tip: str | None) -> None:
    if base is None and tip is None:
        return
    u = robot.urdf or {}
    for opt, given, key in (("--base", base, "base_link"), ("--tip", tip, "tip_link")):
        if given is not None and given != u.get(key):
            have = f"the chain {u.get('base_link')} -> {u.get('tip_link')}" if u else "a robot that is not a URDF"
            raise CLIError(f"{spec}: {opt} {given}: the model was fitted on {have}; it cannot change")


def load_model(spec) -> object:
    """A hykin model file (commands that need the networks: register, export, compensate, serve)."""
    p = Path(spec)
    if p.is_file() and not is_model_file(str(spec)):
        got = f"a {p.suffix} file" if p.suffix else "another kind of file"
        raise CLIError(f"{spec}: expected a hykin model file (written by `hykin fit`), got {got}")
    from ..hybrid.model import HybridModel

    return HybridModel.load(spec)


PayloadKg = typer.Option(None, "--payload-kg", help="Payload (kg, at the TCP) the robot carries while it runs: "
                         "the model deflects under it (default: the robot file's payload).")


def with_payload(mdl, payload_kg: float | None):
    """``mdl`` carrying ``payload_kg`` (:func:`hykin.io.payload.model_with_payload`; None: unchanged). A mass
    that is not finite and >= 0 is refused; one outside the payloads the model was trained on warns."""
    if payload_kg is None:
        return mdl
    from ..io.payload import model_with_payload

    if not (payload_kg >= 0 and payload_kg < float("inf")):
        raise CLIError(f"--payload-kg must be a finite mass >= 0 kg, got {payload_kg}")
    warn_payloads_outside(mdl, payload_kg, f"{payload_kg:g} kg lies")
    warn_payload_no_effect(mdl, None, payload_kg)
    return model_with_payload(mdl, payload_kg)


def note_default_payload(mdl, payload_kg: float | None, extra: dict, path) -> None:
    """One line when ``mdl`` was trained on several payloads but neither ``--payload-kg`` nor a
    ``payload_kg`` column of ``path`` says which one the robot carries: the poses are then at the robot
    file's payload (probe report s40: 0 kg assumed silently, 0.63 mm off at 12 kg)."""
    rng = getattr(mdl, "payload_range_", None)
    if mdl is None or rng is None or payload_kg is not None or "payload_kg" in (extra or {}):
        return
    if not rng.upper_kg > rng.lower_kg:
        return
    console().print(f"note: {path} has no payload_kg column and no --payload-kg was given: the robot file's payload, "
                    f"{mdl.robot_.payload_kg:g} kg, is assumed (the model was trained on {rng.lower_kg:g}-"
                    f"{rng.upper_kg:g} kg)", highlight=False)


def warn_payload_no_effect(mdl, robot, payload_kg: float | None) -> None:
    """One line when ``--payload-kg`` is given but cannot change a pose: the robot (a model's calibrated
    robot) has no joint stiffness, and a model's networks were trained on one payload only."""
    if payload_kg is None:
        return
    rob = getattr(mdl, "robot_", None) or robot
    if rob is None or rob.has_compliance or bool(getattr(mdl, "payload_input_", False)):
        return
    what = "the model's robot" if mdl is not None else f"robot {rob.name!r}"
    nets = " and its networks were trained on one payload" if mdl is not None else ""
    console().print(f"[yellow]warning:[/] --payload-kg {payload_kg:g}: {what} has no joint stiffness{nets}, so the payload "
                    "changes no pose (a robot file with stiffness, or a fit on data with a payload_kg column, models it)",
                    highlight=False)


def warn_payloads_outside(mdl, kg, what: str) -> None:
    """Warn when payloads ``kg`` (kg, scalar or ``(N,)``) lie outside those ``mdl`` was trained on; ``what``
    opens the line (``{n}``: how many lie outside)."""
    from ..io.payload import payload_outside

    n = int(payload_outside(getattr(mdl, "payload_range_", None), kg).sum())
    if n:
        rng = mdl.payload_range_
        console().print(f"[yellow]warning:[/] {what.format(n=n)} outside the payloads the model was trained on "
                        f"({rng.lower_kg:g}-{rng.upper_kg:g} kg): the physics carries {'it' if np.ndim(kg) == 0 else 'them'}, "
                        "the networks hold their "
                        "nearest trained payload", highlight=False)


def warn_orientation_unmeasured(mdl, what: str) -> None:
    """Warn once that ``mdl`` was fitted on positions only when ``what`` (e.g. "the written poses")
    depends on the TCP's orientation: that is the robot file's tool orientation, never measured."""
    meta = getattr(mdl, "metadata", None) or {}
    if mdl is not None and meta.get("has_orientation") is False:
        console().print(f"[yellow]warning:[/] the model was fitted on positions only: its TCP orientation is the robot "
                        f"file's tool orientation, never measured; {what} (use positions, or fit on data with orientations)",
                        highlight=False)


# --------------------------------------------------------------------------- commands


def check_rt_priority(rt_priority: int) -> None:
    """``--rt-priority`` of the bridges and the service: 0 (normal) or a SCHED_FIFO priority 1..99."""
    if not 0 <= rt_priority <= 99:
        raise CLIError(f"--rt-priority must be 0 (normal) or 1..99 (SCHED_FIFO), got {rt_priority}")


def parse_axis_signs(text: str | None, dof: int):
    """``--axis-signs`` (comma-separated 1 / -1 per joint) -> ``(dof,)`` array, or None when not given."""
    if text is None:
        return None
    try:
        s = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise CLIError(f"--axis-signs: expected {dof} comma-separated values of 1 or -1, got {text!r}") from None
    if s.shape != (dof,) or not np.all(np.abs(s) == 1):
        raise CLIError(f"--axis-signs: expected {dof} comma-separated values of 1 or -1, got {text!r}")
    return s


def temperature_of(mdl, extra: dict, path) -> np.ndarray | None:
    """The file's temperature column for a model with a thermal coefficient (note when it is missing)."""
    from ..calibration.thermal import temperature_from

    th = getattr(mdl, "thermal_", None)
    if th is None or th.coefficient_per_k == 0.0:
        t = temperature_from(extra, str(path))  # checked (units) even when unused
        if t is not None and mdl is not None:
            why = "its fit kept none" if th is not None else "its training data had one temperature, or none"
            console().print(f"[yellow]note:[/] {path} has a temperature column, but the model has no thermal expansion "
                            f"({why}): the temperatures are not used", highlight=False)
        return None
    t = temperature_from(extra, str(path))
    if t is None:
        console().print(f"[yellow]note:[/] the model compensates thermal expansion ({th.coefficient_per_k * 1e6:.2f} µm/m/K) "
                         f"but {path} has no temperature_c column: results at the reference {th.reference_c:.2f} °C")
        return t
    lo, hi = th.range_c
    n_out = int(np.sum((t < lo) | (t > hi)))
    if n_out:
        console().print(f"[yellow]warning:[/] {n_out} of {len(t)} rows of {path} lie outside the temperatures the model was "
                        f"trained on ({lo:.2f}-{hi:.2f} °C): its expansion is extrapolated there", highlight=False)
    return t


def write_rows(rows: dict, out: Path) -> None:
    """Write command output rows (column name -> ``(N,)`` values) as CSV (:data:`hykin.io.csv_writer.ROWS_STYLE`),
    creating the output folder."""
    from ..io.csv_writer import ROWS_STYLE, write_csv

    out.parent.mkdir(parents=True, exist_ok=True)
    write_csv(out, rows, ROWS_STYLE)


_INTERRUPT = {"said": False}


def mark_interrupt_said() -> None:
    """A command said why it stopped on Ctrl-C (and how to go on): the entry point adds nothing."""
    _INTERRUPT["said"] = True


def interrupt_said() -> bool:
    """Whether a command already said why it stopped on Ctrl-C (:func:`mark_interrupt_said`)."""
    return _INTERRUPT["said"]
