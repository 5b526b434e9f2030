"""Exceptions and warnings of the hybrid model (a module of their own so that every hybrid module
can raise them without importing :mod:`hykin.hybrid.model`)."""

from __future__ import annotations

__all__ = ["FitWarning", "HybridError", "OutOfRangeWarning"]


class HybridError(ValueError):
    """Bad input to a hybrid model (shape, NaN, unfitted model...)."""


class OutOfRangeWarning(UserWarning):
    """Queries outside the joint range the networks were trained on."""


class FitWarning(UserWarning):
    """A note on the data or the result of ``fit``: repeated rows, too few held-out rows to judge the
    networks, networks that do worse than the calibrated model on the held-out rows."""
