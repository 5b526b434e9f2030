"""Progress of the hybrid model's fit, readable on a terminal AND in a log file.

* On a terminal (stderr is a TTY): a rich bar per network counting optimiser steps, with elapsed
  time, ETA and the current losses.
* Otherwise (a log file, a pipe, CI): plain lines — one when a stage starts and ends, and during a
  stage one line at least every ``interval_s`` (10 s; environment variable
  ``HYKIN_PROGRESS_INTERVAL_S``) with the steps done, the share, elapsed time and an ETA.

Stages: ``calibration`` (LM iterations: no total is known, so the line gives iterations and the cost)
and ``training pos net`` / ``training rot net`` (optimiser steps). When a time budget cut training
short, :meth:`Progress.budget_cut` says how far it got.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable

__all__ = ["LogLines", "Progress", "format_duration"]

DEFAULT_INTERVAL_S = 10.0


def format_duration(s: float) -> str:
    """``"42 s"``, ``"3 min 05 s"``, ``"1 h 02 min"``."""
    if not math.isfinite(s):
        return "?"
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


class LogLines:
    """Plain progress lines for one stage, at most one per ``interval_s`` (first and last always).
    ``clock``: seconds (monotonic); ``write``: takes one line (default: stderr)."""

    def __init__(self, stage: str, *, interval_s: float = DEFAULT_INTERVAL_S, clock: Callable[[], float] = time.monotonic,
                 write: Callable[[str], None] | None = None, unit: str = "steps"):
        self.stage, self.interval_s, self.clock, self.unit = stage, float(interval_s), clock, unit
        self.write = write or (lambda s: print(s, file=sys.stderr, flush=True))
        self.t0 = self.clock()
        self.last = -math.inf
        self.first = None  # (time, done) of the first update: the ETA's rate excludes start-up work
        self.write(f"{stage}: started")

    def update(self, done: int, total: int | None, info: str = "", final: bool = False) -> bool:
        """Record progress; writes a line when ``interval_s`` passed since the last one (or ``final``).
        Returns whether a line was written."""
        now = self.clock()
        if not final and now - self.last < self.interval_s:
            return False
        self.last = now
        el = now - self.t0
        if self.first is None:
            self.first = (now, done)
        if total:
            frac = done / total
            t1, d1 = self.first
            eta = (now - t1) / (done - d1) * (total - done) if done > d1 and now > t1 else None
            line = (f"{self.stage}: {done:,}/{total:,} {self.unit} ({100 * frac:.0f} %), {format_duration(el)} elapsed, "
                    f"ETA {format_duration(eta) if eta is not None else 'estimating'}"
                    if done < total else
                    f"{self.stage}: {done:,}/{total:,} {self.unit} (100 %), {format_duration(el)} elapsed, ETA 0 s")
        else:
            line = f"{self.stage}: {done:,} {self.unit}, {format_duration(el)} elapsed, ETA unknown"
        self.write(line + (f", {info}" if info else ""))
        return True

    def done(self, info: str = "") -> None:
        self.write(f"{self.stage}: done in {format_duration(self.clock() - self.t0)}" + (f" ({info})" if info else ""))


class Progress:
    """Context manager for one fit. ``callback(key)`` gives :func:`hykin.hybrid.train.train_net` a
    callback ``(step, total_steps, train_loss, val_loss)`` for network ``key`` ("pos": losses shown in
    mm, "rot": in deg); :meth:`calibration` a ``(iteration, cost)`` callback for the calibration.
    Disabled (``enabled=False``): every callback is None and nothing is printed.
    ``tty``: force the terminal bar (True) or the log lines (False); default ``stderr.isatty()``."""

    def __init__(self, enabled: bool, *, tty: bool | None = None, interval_s: float | None = None,
                 clock: Callable[[], float] = time.monotonic, write: Callable[[str], None] | None = None):
        self.enabled = enabled
        self.tty = sys.stderr.isatty() if tty is None else tty
        env = os.environ.get("HYKIN_PROGRESS_INTERVAL_S")
        self.interval_s = float(interval_s if interval_s is not None else env if env else DEFAULT_INTERVAL_S)
        self.clock, self.write = clock, write
        self.prog = None
        self.logs: dict[str, LogLines] = {}

    def __enter__(self):
        if self.enabled and self.tty:
            try:
                from rich.progress import BarColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
                from rich.progress import Progress as RichProgress

                self.prog = RichProgress(TextColumn("{task.description}"), BarColumn(),
                                         TextColumn("{task.completed:,}/{task.total:,} steps"),
                                         TextColumn("{task.fields[info]}"), TimeElapsedColumn(),
                                         TextColumn("ETA"), TimeRemainingColumn(), transient=False)
                self.prog.__enter__()
            except ImportError:  # pragma: no cover
                self.prog = None
        return self

    def __exit__(self, *exc):
        if self.prog is not None:
            self.prog.__exit__(*exc)

    def _lines(self, stage: str, unit: str = "steps") -> LogLines:
        self.logs[stage] = LogLines(stage, interval_s=self.interval_s, clock=self.clock, write=self.write, unit=unit)
        return self.logs[stage]

    def say(self, line: str) -> None:
        """One plain line (a stage note) when enabled."""
        if self.enabled:
            (self.write or (lambda s: print(s, file=sys.stderr, flush=True)))(line)

    def callback(self, key: str):
        if not self.enabled:
            return None
        unit, f = ("mm", 1e3) if key == "pos" else ("deg", 180 / math.pi)
        desc = f"training {key} net"
        info = lambda tl, vl: f"train {tl * f:.4g} {unit}" + (f", val {vl * f:.4g} {unit}" if vl == vl else "")
        if self.prog is not None:
            task = []  # created at the first call, when the total is known (no "0/None" bar)

            def cb(step, total, train_loss, val_loss):
                if not task:
                    task.append(self.prog.add_task(desc, total=total, info=""))
                self.prog.update(task[0], completed=step, total=total, info=info(train_loss, val_loss))

            return cb
        log = self._lines(desc)

        def cb_log(step, total, train_loss, val_loss):
            log.update(step, total, info(train_loss, val_loss), final=step >= total)

        return cb_log

    def calibration(self, n_poses: int):
        """A ``(iteration, cost)`` callback for :func:`hykin.calibration.calibrate.calibrate` (None when
        disabled); the stage line says it started. Plain lines on a terminal too (no total is known)."""
        if not self.enabled:
            return None
        log = self._lines(f"calibration ({n_poses:,} poses)", unit="LM iterations")
        return lambda it, cost: log.update(int(it), None, f"cost {cost:.4g}")

    def stage(self, name: str) -> LogLines:
        """A stage without steps: its "started" line now, ``.done()`` for its "done in" line (silent when disabled)."""
        return self._lines(name, unit="") if self.enabled else LogLines(name, write=lambda s: None)

    def stage_done(self, prefix: str, info: str = "") -> None:
        for k, log in self.logs.items():
            if k.startswith(prefix):
                log.done(info)

    def budget_cut(self, key: str, result) -> None:
        """Say how far a network got when the time budget stopped it (``result``: its TrainResult)."""
        if self.enabled and getattr(result, "stopped", "") == "max_seconds":
            planned = getattr(result, "planned_steps", 0)
            share = f" ({100 * result.steps / planned:.0f} %)" if planned else ""
            self.say(f"training {key} net: time budget reached after {result.steps:,} of {planned:,} steps{share}, "
                     f"epoch {result.epochs}; the best weights so far are kept")
