"""`hykin fit` options -> :class:`hykin.hybrid.model.HybridModel` settings (one mapping for the CLI,
the sweep trials and the fleet, so the same options give the same model).

* :data:`FIT_OPTIONS` — option name (the CLI's ``--option`` with underscores) -> default.
* :func:`calibration_options` — ``--orientation-weight`` / ``--max-deviation`` -> ``calibrate`` kwargs.
* :func:`model_kwargs` — all fit options -> ``HybridModel(robot, **kwargs)`` keyword arguments.

Bad values raise ValueError with a one-line message naming the option.
"""

from __future__ import annotations

import re

import numpy as np

__all__ = ["DEVICES", "FIT_OPTIONS", "calibration_options", "is_device", "model_kwargs"]

#: `hykin fit` option -> default (None: the recipe's / unset).
FIT_OPTIONS: dict = {
    "arch": "default", "recipe": "default", "calibrate": True, "device": "cpu", "seed": 0,
    "max_minutes": None, "thermal": "auto", "min_steps": None, "max_epochs": None,
    "orientation_weight": "auto", "max_deviation": None, "prior": None, "region_cv": False, "fade_cv": 0,
    "outliers": "drop", "outlier_ratio": 12.0,
}

_THERMAL = {"auto": "auto", "on": True, "off": False}


def calibration_options(orientation_weight="auto", max_deviation: str | None = None,
                        prior: list[str] | None = None, outliers: str = "drop", outlier_ratio: float = 12.0) -> dict:
    """``calibrate`` keyword arguments from ``--orientation-weight`` (m/rad or 'auto'),
    ``--max-deviation`` (KIND=VALUE[,...]; only the kinds given bound their kind), ``--prior``
    (KIND=VALUE strings), ``--outliers`` (drop, warn, keep) and ``--outlier-ratio`` (> 1; defaults are
    left out of the keywords); ValueError on bad values."""
    from ..calibration.outliers import DEFAULT_RATIO, OUTLIER_MODES

    from ..calibration.checks import parse_max_deviation
    from ..calibration.priors import DEFAULT_PRIORS, parse_kind_values, parse_priors

    kw: dict = {}
    if orientation_weight != "auto":
        try:
            w = float(orientation_weight)
        except (TypeError, ValueError):
            raise ValueError(f"--orientation-weight must be a number (m/rad) or 'auto', got {orientation_weight!r}") from None
        if not (w > 0 and w < float("inf")):
            raise ValueError(f"--orientation-weight must be > 0, got {orientation_weight!r}")
        kw["orientation_weight_m_per_rad"] = w
    if max_deviation:
        parse_max_deviation(max_deviation)  # validated; only the kinds given bound their kind
        kw["max_deviation"] = parse_kind_values(max_deviation, "--max-deviation", ())
    if prior:
        pri = parse_priors(prior)
        kw["priors"] = {k: v for k, v in pri.items() if v != DEFAULT_PRIORS[k]}  # kinds given (resolved: valid)
    if outliers not in OUTLIER_MODES:
        raise ValueError(f"--outliers must be one of {', '.join(OUTLIER_MODES)}, got {outliers!r}")
    try:
        ratio = float(outlier_ratio)
    except (TypeError, ValueError):
        ratio = float("nan")
    if not (1 < ratio < float("inf")):
        raise ValueError(f"--outlier-ratio must be a number > 1 (typical errors), got {outlier_ratio!r}")
    if outliers != "drop":
        kw["outliers"] = outliers
    if ratio != DEFAULT_RATIO:
        kw["outlier_ratio"] = ratio
    return kw


#: the devices a fit runs on (as `hykin fit --device`), plus ``cuda:N`` for one GPU of several
DEVICES = ("cpu", "cuda", "auto")


def is_device(value) -> bool:
    """Whether ``value`` names a device a fit runs on (:data:`DEVICES` or ``cuda:N``)."""
    return isinstance(value, str) and (value in DEVICES or re.fullmatch(r"cuda:\d+", value) is not None)


def model_kwargs(**options) -> dict:
    """``HybridModel`` keyword arguments for the `hykin fit` ``options`` (names of :data:`FIT_OPTIONS`;
    missing ones take their defaults). ``device="auto"`` resolves to cuda when available."""
    unknown = sorted(set(options) - set(FIT_OPTIONS))
    if unknown:
        raise ValueError(f"unknown fit option {unknown[0]!r} (known: {', '.join(FIT_OPTIONS)})")
    o = {**FIT_OPTIONS, **options}
    for name in ("seed", "min_steps", "max_epochs", "fade_cv"):  # 1.9 or "3" silently became 1 / 3 (probe s41 AG)
        v = o[name]
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer))):
            raise ValueError(f"{name} must be an integer, got {v!r}")
    for name in ("calibrate", "region_cv"):  # "false" was true
        if not isinstance(o[name], (bool, np.bool_)):
            raise ValueError(f"{name} must be true or false, got {o[name]!r}")
    if not is_device(o["device"]):
        raise ValueError(f"device must be auto, cpu, cuda or cuda:N, got {o['device']!r}")
    kw: dict = {}
    if o["max_minutes"] is not None:
        kw["max_seconds"] = float(o["max_minutes"]) * 60
    if o["min_steps"] is not None:
        if int(o["min_steps"]) < 0:
            raise ValueError(f"--min-steps must be >= 0, got {o['min_steps']}")
        kw.setdefault("recipe_kw", {})["min_steps"] = int(o["min_steps"])
    if o["max_epochs"] is not None:
        if int(o["max_epochs"]) < 1:
            raise ValueError(f"--max-epochs must be >= 1, got {o['max_epochs']}")
        kw.setdefault("recipe_kw", {})["max_epochs"] = int(o["max_epochs"])
    if o["thermal"] not in _THERMAL:
        raise ValueError(f"--thermal must be auto, on or off, got {o['thermal']!r}")
    fade_cv = int(o["fade_cv"])
    if fade_cv == 1 or fade_cv < 0:
        raise ValueError(f"--fade-cv must be 0 (off) or >= 2 regions, got {fade_cv}")
    cal_kw = calibration_options(o["orientation_weight"], o["max_deviation"], o["prior"], o["outliers"], o["outlier_ratio"])
    if o["region_cv"]:
        cal_kw["select"] = "region-cv"
    device = o["device"]
    if device == "auto":
        import torch

        device = "cuda" if torch.cuda.is_available() else "cpu"
    return dict(arch=o["arch"], recipe=o["recipe"], calibrate=bool(o["calibrate"]), device=device, seed=int(o["seed"]),
                thermal=_THERMAL[o["thermal"]], calibrate_kw=cal_kw, fade_cv=fade_cv, **kw)
