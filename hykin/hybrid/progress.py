"""Optional rich progress bar over the training epochs of the hybrid model's networks."""

from __future__ import annotations

import math

__all__ = ["Progress"]


class Progress:
    """Context manager; ``callback(key)`` gives :func:`hykin.hybrid.train.train_net` an epoch callback
    for network ``key`` ("pos": losses shown in mm, "rot": in deg), or None when disabled or rich is
    not installed."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.prog = None

    def __enter__(self):
        if self.enabled:
            try:
                from rich.progress import (
                    BarColumn,
                    TextColumn,
                    TimeElapsedColumn,
                )
                from rich.progress import Progress as RichProgress

                self.prog = RichProgress(TextColumn("{task.description}"), BarColumn(),
                                         TextColumn("{task.completed}/{task.total}"),
                                         TextColumn("{task.fields[info]}"), TimeElapsedColumn(), transient=True)
                self.prog.__enter__()
            except ImportError:  # pragma: no cover
                self.prog = None
        return self

    def __exit__(self, *exc):
        if self.prog is not None:
            self.prog.__exit__(*exc)

    def callback(self, key: str):
        if self.prog is None:
            return None
        unit, f = ("mm", 1e3) if key == "pos" else ("deg", 180 / math.pi)
        task = self.prog.add_task(f"training {key} net", total=None, info="")

        def cb(epoch, total, train_loss, val_loss):
            self.prog.update(task, completed=epoch, total=total,
                             info=f"train {train_loss * f:.4g} {unit}  val {val_loss * f:.4g} {unit}")

        return cb
