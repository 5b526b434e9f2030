"""One JSON codec for :class:`~hykin.kinematics.robot.Robot`: every field (any convention, URDF
included) as JSON-safe data in SI units, and back.

Two file formats embed robots and must stay byte-identical to what earlier versions wrote; they
differ only in how a non-finite number (in practice: ``inf`` stiffness = rigid joint) is spelt and
in the key order:

* model files (:mod:`hykin.io.modelfile`): ``inf_as="string"``, non-finite as ``"inf"``/``"-inf"``
  (``"nan"``); scalars (name, convention, joint_type, payload_kg, source) before the arrays;
* truth files (:mod:`hykin.sim.simulate`): ``inf_as="null"``, ``inf`` as JSON ``null``
  (human-readable "rigid"; NaN stays a JSON ``NaN``); arrays before ``payload_kg`` and ``source``.

:func:`robot_from_json` reads both spellings (``null`` -> ``inf``, ``"inf"``/``"-inf"``/``"nan"``
-> float) whatever the file. Floats round-trip through JSON (repr) without loss.
"""

from __future__ import annotations

import math

import numpy as np

from ..kinematics.robot import Robot

__all__ = ["OPTIONAL_FIELDS", "REQUIRED_FIELDS", "ROBOT_ARRAYS", "RobotDictError", "robot_from_json", "robot_to_json"]

#: The array fields of a Robot, in the order both formats write them.
ROBOT_ARRAYS = (
    "a_m", "alpha_rad", "d_m", "theta_rad", "beta_rad", "lower", "upper", "origin_xyz_m", "origin_rpy_rad",
    "axis", "mass_kg", "com_m", "stiffness_nm_per_rad", "base", "tool", "gravity_base",
)
#: Fields without a default in :class:`Robot`: a robot entry lacking one of them cannot be read.
REQUIRED_FIELDS = ("name", "convention", "a_m", "alpha_rad", "d_m", "theta_rad", "lower", "upper")


class RobotDictError(ValueError):
    """A robot entry of a JSON document is malformed. ``missing`` names a missing field (or None)."""

    def __init__(self, message: str, missing: str | None = None):
        super().__init__(message)
        self.missing = missing


def _encode(x, inf_as: str):
    """Nested lists of floats; a non-finite number as ``"inf"``/``"-inf"``/``"nan"`` or ``None``."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0:
        v = float(a)
        if math.isfinite(v):
            return v
        if math.isnan(v):  # not a value hykin writes; kept visible, never turned into inf
            return v if inf_as == "null" else "nan"
        return None if inf_as == "null" else ("inf" if v > 0 else "-inf")
    return [_encode(v, inf_as) for v in a]


def _decode(x):
    """Inverse of :func:`_encode` for either spelling (``None`` = ``inf``, i.e. a rigid joint)."""
    if isinstance(x, list):
        return [_decode(v) for v in x]
    if x is None:
        return math.inf
    if isinstance(x, str):
        return float(x)
    return x


def robot_to_json(robot: Robot, *, inf_as: str = "string") -> dict:
    """Every field of ``robot`` as JSON-safe data (SI). ``inf_as``: ``"string"`` (model files,
    scalars first) or ``"null"`` (truth files, arrays first); see the module docstring."""
    if inf_as not in ("string", "null"):
        raise ValueError(f"inf_as must be 'string' or 'null', got {inf_as!r}")
    head = {"name": robot.name, "convention": robot.convention, "joint_type": list(robot.joint_type)}
    arrays = {k: _encode(getattr(robot, k), inf_as) for k in ROBOT_ARRAYS}
    tail = {"payload_kg": float(robot.payload_kg), "source": robot.source}
    out = {**head, **tail, **arrays} if inf_as == "string" else {**head, **arrays, **tail}
    return {**out, **_optional_to_json(robot)}


#: Optional fields, written only when set (files of robots without them stay as earlier versions
#: wrote them): URDF mimic table, joint names, and the URDF text with its base and tip links.
OPTIONAL_FIELDS = ("mimic", "joint_names", "urdf")


def _optional_to_json(robot: Robot) -> dict:
    out = {}
    if robot.mimic is not None:
        out["mimic"] = _encode(robot.mimic, "string")
    if robot.joint_names is not None:
        out["joint_names"] = list(robot.joint_names)
    if robot.urdf is not None:
        out["urdf"] = {k: str(v) for k, v in robot.urdf.items()}
    return out


def robot_from_json(d: dict, *, required=REQUIRED_FIELDS) -> Robot:
    """A :class:`Robot` from :func:`robot_to_json` output (either spelling of ``inf``).

    ``required``: fields that must be present (model files require all of them); any other missing
    field takes the :class:`Robot` default. Raises :class:`RobotDictError` (missing field, wrong
    type) or :class:`~hykin.kinematics.robot.RobotFileError` (inconsistent fields).
    """
    if not isinstance(d, dict):
        raise RobotDictError("expected an object")
    for k in required:
        if k not in d:
            raise RobotDictError(f"missing field '{k}'", missing=k)
    kw = {k: d[k] for k in ("name", "convention") if k in d}
    try:
        for k in ROBOT_ARRAYS:
            if k in d:
                kw[k] = np.array(_decode(d[k]), dtype=np.float64)
        if "joint_type" in d:
            kw["joint_type"] = tuple(d["joint_type"])
        if "payload_kg" in d:
            kw["payload_kg"] = float(d["payload_kg"])
        if "source" in d:
            kw["source"] = d["source"]
        if d.get("mimic") is not None:
            kw["mimic"] = np.array(_decode(d["mimic"]), dtype=np.float64)
        if d.get("joint_names") is not None:
            kw["joint_names"] = tuple(str(x) for x in d["joint_names"])
        if d.get("urdf") is not None:
            if not isinstance(d["urdf"], dict):
                raise TypeError("'urdf' must be an object")
            kw["urdf"] = {str(k): str(v) for k, v in d["urdf"].items()}
    except (TypeError, ValueError) as e:
        raise RobotDictError(f"{type(e).__name__}: {e}") from None
    try:
        return Robot(**kw)
    except TypeError as e:
        raise RobotDictError(f"{type(e).__name__}: {e}") from None
