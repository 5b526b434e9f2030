"""The generated battery: run a drawn campaign through the command line as a user does and judge it.

:func:`run_campaign` writes a :class:`hykin.sim.random_campaigns.Campaign` to a folder, runs
``hykin fit ROBOT train.csv -o model.hykin`` and ``hykin evaluate model.hykin test.csv --json`` through
``run_cli`` (a callable ``argv -> (exit code, stdout, stderr)``: the test suite and the benchmark pass
an in-process runner of :func:`hykin.cli.main`; this module does not import the CLI, which sits in a
higher layer) and returns a :class:`Verdict`:

* a correct input (``expect == "model"``) passes when ``fit`` and ``evaluate`` succeed and the held-out
  mean position error of the model is at most ``FLOOR_FACTOR × floor_mm + FLOOR_SLACK_MM``, where
  ``floor_mm`` is the mean |measured − true| position of the held-out rows (what a perfect model
  scores). A refusal of a correct input fails ("refused a correct input");
* a mistake (``expect == "refuse"``) passes when ``fit`` exits non-zero with exactly one
  ``hykin: error:`` line that names the cause (one of the campaign's keywords) and writes no model;
  a model fails ("accepted a mistake");
* ``expect == "model-or-refuse"``: either of the two above passes.

Any traceback, a second error line or a model file left behind by a refusal fails. Every verdict
carries the command lines and ``--family F --seed S`` that reproduce it.
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .random_campaigns import Campaign

__all__ = ["FIT_FAST", "FLOOR_FACTOR", "FLOOR_SLACK_MM", "Verdict", "judge", "run_campaign"]

FLOOR_FACTOR = 1.5
"""A model passes when its held-out mean position error is within this factor of the noise floor..."""
FLOOR_SLACK_MM = 0.01
"""... plus this much (mm): the floor of a 0.005 mm-noise campaign is below what 100 poses identify."""
FIT_FAST = ["--max-epochs", "3", "--min-steps", "0"]
"""Short network training: the battery judges the calibration and the checks; the networks' own
accuracy is measured by the other benchmarks."""


@dataclass
class Verdict:
    """What hykin did with one campaign. ok: the property held. outcome: "model", "refused" or
    "crash". cause: why it failed (or what passed). error_mm / floor_mm: held-out mean position error
    of the model and the noise floor (mm; nan without a model). line: the refusal line."""

    family: str
    seed: int
    ok: bool
    outcome: str
    cause: str
    error_mm: float = float("nan")
    floor_mm: float = float("nan")
    line: str = ""
    commands: tuple[str, ...] = ()

    def reproduce(self) -> str:
        """How to reproduce: the benchmark command and the CLI command lines that ran."""
        head = f"python benchmarks/bench_battery.py --families {self.family} --seed {self.seed} --draws 1"
        return "\n".join([head, *("  hykin " + c for c in self.commands)])

    def summary(self) -> str:
        """One line: family, seed, verdict, cause."""
        return f"{self.family} seed={self.seed}: {'PASS' if self.ok else 'FAIL'} ({self.outcome}) {self.cause}"


def _error_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("hykin: error:")]


def _other_error_line(err: str) -> str:
    """The message of an error hykin did not print as ``hykin: error:`` (a usage panel of the
    command-line parser, say), without the panel's frame."""
    text = [ln.strip(" │╭╮╰╯─") for ln in err.splitlines()]
    text = [t for t in text if t]
    hits = [t for t in text if "rror" in t or "option" in t.lower()]
    return (hits or text or [""])[-1]


def judge(c: Campaign, fit: tuple[int, str, str], evaluation: tuple[int, str, str] | None,
          model_written: bool, commands=()) -> Verdict:
    """The verdict for ``c`` from the ``fit`` and ``evaluate`` runs ``(exit code, stdout, stderr)``
    (``evaluation`` None when fit failed) and whether a model file exists after fit."""
    v = Verdict(c.family, c.seed, False, "model", "", floor_mm=c.floor_mm, commands=tuple(commands))
    code, _, err = fit
    if code == "crash" or "Traceback" in err:
        v.outcome, v.cause = "crash", "crash: " + (err.strip().splitlines() or ["?"])[-1][:300]
        return v
    if code != 0:
        v.outcome = "refused"
        lines = _error_lines(err)
        v.line = lines[0] if lines else _other_error_line(err)
        if model_written:
            v.cause = f"refused but left a model file: {v.line[:300]}"
        elif c.expect == "model":
            v.cause = f"refused a correct input: {v.line[:300]}"
        elif len(lines) != 1:
            v.cause = f"refusal with {len(lines)} 'hykin: error:' lines: {v.line[:300]}"
        elif not any(k in v.line.lower() for k in c.causes):
            v.cause = f"refused without naming the cause (expected one of {list(c.causes)}): {v.line[:300]}"
        else:
            v.ok, v.cause = True, f"refused naming the cause: {v.line[:200]}"
        return v
    ecode, eout, eerr = evaluation if evaluation is not None else ("crash", "", "no evaluation")
    if ecode != 0 or "Traceback" in eerr:
        v.outcome = "crash" if ecode == "crash" else "refused"
        v.cause = f"evaluate failed on the fitted model: {(eerr.strip().splitlines() or ['?'])[-1][:300]}"
        return v
    try:
        v.error_mm = float(json.loads(eout)["stats"]["hybrid"]["pos_mean_mm"])
    except (ValueError, KeyError, TypeError) as e:
        v.cause = f"evaluate --json output unreadable ({e})"
        return v
    bound = FLOOR_FACTOR * c.floor_mm + FLOOR_SLACK_MM
    if c.expect == "refuse":
        v.cause = f"accepted a mistake: model with {v.error_mm:.4f} mm held-out (floor {c.floor_mm:.4f} mm)"
    elif not v.error_mm <= bound:
        v.cause = (f"model {v.error_mm:.4f} mm on held-out poses > {FLOOR_FACTOR:g} x floor {c.floor_mm:.4f} mm "
                   f"+ {FLOOR_SLACK_MM:g} mm (silent wrong answer)")
    else:
        v.ok, v.cause = True, f"model {v.error_mm:.4f} mm within {bound:.4f} mm"
    return v


def run_campaign(c: Campaign, folder, run_cli: Callable[[list[str]], tuple[int, str, str]],
                 fit_options: list[str] | None = None) -> Verdict:
    """Write ``c`` into ``folder``, run fit (with ``fit_options``, default :data:`FIT_FAST`) and
    evaluate through ``run_cli``, and :func:`judge` the result."""
    folder = Path(folder)
    p = c.write(folder)
    model = folder / "model.hykin"
    fit_argv = ["fit", str(p["robot"]), str(p["train"]), "-o", str(model), *(FIT_FAST if fit_options is None else fit_options),
                *c.fit_args]
    cmds = [shlex.join(fit_argv)]
    fit = run_cli(fit_argv)
    evaluation = None
    if fit[0] == 0:
        eval_argv = ["evaluate", str(model), str(p["test"]), "--json", *c.eval_args]
        cmds.append(shlex.join(eval_argv))
        evaluation = run_cli(eval_argv)
    return judge(c, fit, evaluation, model_written=model.exists(), commands=cmds)
