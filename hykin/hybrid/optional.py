"""Optional steps of :meth:`hykin.hybrid.model.HybridModel.fit`: what may fail without losing the model.

The calibration and the networks are the model; everything else ``fit`` does is an extra that a
model can do without: the thermal coefficient (``thermal="auto"``), the region-blocked choice of the
calibration's parameters (``--region-cv``), the uncertainty bands (and within them the extrapolation
growth of the calibrated model), the measured fade (``fade_cv``). Each runs through
:func:`optional_step`: a failure becomes ONE :class:`OptionalStepWarning` naming the step and the cause,
is recorded in the model's metadata (``meta_["optional_steps_failed"]``, saved in the model file), and
the fit goes on without that step, so an hour of training is never lost to an extra.
"""

from __future__ import annotations

import warnings

__all__ = ["OptionalStepWarning", "optional_step"]


class OptionalStepWarning(UserWarning):
    """An optional step of ``fit`` failed; the model was kept without it (one per failed step)."""


def optional_step(name: str, record: dict, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``; on any ``Exception`` warn once (:class:`OptionalStepWarning`), store
    ``record[name]`` = the one-line cause and return None. KeyboardInterrupt is not caught."""
    try:
        return fn(*args, **kwargs)
    except Exception as e:  # noqa: BLE001 - an optional step never loses the fitted model
        line = (str(e).strip().splitlines() or [type(e).__name__])[0]
        record[name] = f"{type(e).__name__}: {line}"
        warnings.warn(f"optional step '{name}' failed and was skipped ({record[name]}); the fitted model is kept "
                      "without it", OptionalStepWarning, stacklevel=3)
        return None
