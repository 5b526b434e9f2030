"""The one up-front check of `hykin fit` options written in a sweep or fleet file (and of their data units).

Sweep ``[grid]`` / ``[random]`` values and fleet ``[robot.fit]`` values are checked here, before Ray
starts, so a wrong value is one line naming the file, the table and the key, not a trial or robot that
fails (or, worse, runs with a silently converted value: ``calibrate = "false"`` is ``bool("false")``,
true; ``seed = 1.9`` is ``int(1.9)``, 1) after Ray started.

* :data:`OPTION_TYPES` — option name -> the TOML type(s) it takes (a bool is never an int).
* :func:`check_option` — one value: its type, then its meaning (architecture / recipe / device names and
  the `hykin fit` mapping :func:`hykin.hybrid.fit_options.model_kwargs`); SpecError on a mistake.
* :func:`data_units` — the ``length_unit`` / ``angle_unit`` keys of a table: the units of its data files,
  as `hykin fit --length-unit / --angle-unit` (passed to :func:`hykin.io.dataset_files.read_dataset`).
"""

from __future__ import annotations

from pathlib import Path

from ..hybrid.fit_options import DEVICES, is_device, model_kwargs
from .files import SpecError

__all__ = ["DEVICES", "OPTION_TYPES", "check_option", "data_units", "units_options"]

#: option -> accepted TOML type(s); ``n_train`` is the sweep's (a training-set size), the rest are `hykin fit`'s
OPTION_TYPES: dict = {
    "arch": str, "recipe": str, "calibrate": bool, "device": str, "seed": int, "max_minutes": (int, float),
    "thermal": str, "min_steps": int, "max_epochs": int, "orientation_weight": (str, int, float),
    "max_deviation": str, "prior": list, "region_cv": bool, "fade_cv": int, "outliers": str,
    "outlier_ratio": (int, float), "n_train": int,
}

def _type_name(t) -> str:
    """``int`` / ``bool`` / ``str`` / ``list``, or ``a number`` / ``a string or a number`` for a tuple."""
    if t == (int, float):
        return "a number"
    if isinstance(t, tuple):
        return "a string or a number"
    return t.__name__


def _type_ok(t, v) -> bool:
    """``v`` is of type(s) ``t``; a bool is only a bool (TOML ``true`` is never 1)."""
    if isinstance(v, bool):
        return t is bool
    return isinstance(v, t)


def check_option(path: Path, where: str, key: str, value) -> None:
    """SpecError (one line: ``path``, ``where`` e.g. ``"[grid] "`` or ``"[[robot]] 'a' [robot.fit] "``, the key
    and value) unless ``value`` is a valid ``key`` option: its type (:data:`OPTION_TYPES`), a known
    architecture / recipe, a device of :data:`DEVICES` (or ``cuda:N``), ``n_train >= 1``, and what
    :func:`hykin.hybrid.fit_options.model_kwargs` accepts (the `hykin fit` mapping)."""
    head = f"{path}: {where}{key} = {value!r}"
    t = OPTION_TYPES[key]
    if not _type_ok(t, value):
        raise SpecError(f"{head}: expected {_type_name(t)}")
    if key == "prior" and not all(isinstance(x, str) for x in value):
        raise SpecError(f"{head}: expected a list of KIND=VALUE strings")
    if key == "n_train":
        if value < 1:
            raise SpecError(f"{head}: must be >= 1")
        return
    if key == "device":
        if not is_device(value):
            raise SpecError(f"{head}: unknown device (known: {', '.join(DEVICES)}, or cuda:N)")
        return
    _check_name(head, key, value)
    try:
        model_kwargs(**{key: value})
    except ValueError as e:
        raise SpecError(f"{head}: {e}") from None


def _check_name(head: str, key: str, value) -> None:
    """SpecError when ``key`` is ``arch`` / ``recipe`` and ``value`` names no architecture / recipe."""
    if key == "arch":
        from ..hybrid.nets import list_architectures

        if value not in list_architectures():
            raise SpecError(f"{head}: unknown architecture (known: {', '.join(list_architectures())})")
    elif key == "recipe":
        from ..hybrid.train import RECIPES

        if value not in RECIPES:
            raise SpecError(f"{head}: unknown recipe (known: {', '.join(RECIPES)})")


def data_units(path: Path, where: str, table: dict) -> tuple[str, str]:
    """``(length_unit, angle_unit)`` of ``table``'s data files (defaults ``"m"``, ``"rad"``): the units of
    x, y, z and of the joint columns, as `hykin fit --length-unit / --angle-unit`; SpecError naming the key
    when a value is not one :func:`hykin.io.dataset_files.read_dataset` reads."""
    from ..io.dataset import ANGLE_UNITS, LENGTH_UNITS

    out = []
    for key, default, known in (("length_unit", "m", LENGTH_UNITS), ("angle_unit", "rad", ANGLE_UNITS)):
        v = table.get(key, default)
        if not isinstance(v, str) or v not in known:
            raise SpecError(f"{path}: {where}{key} = {v!r}: expected one of {', '.join(known)} "
                            "(the unit of the data files' " + ("x, y, z)" if key == "length_unit" else "joint columns)"))
        out.append(v)
    return out[0], out[1]


def units_options(length_unit: str, angle_unit: str) -> dict:
    """The units as options of an inputs hash (``--resume``): empty for the defaults (m, rad), so a run
    recorded before the unit keys existed keeps its hash."""
    return {} if (length_unit, angle_unit) == ("m", "rad") else {"length_unit": length_unit, "angle_unit": angle_unit}
