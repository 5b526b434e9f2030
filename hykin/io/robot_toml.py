"""TOML robot files (DESIGN.md §3): parse a robot-file dictionary into a :class:`Robot`, load and
save ``.toml`` files.

Reading is strict: unknown keys are errors with a "did you mean" suggestion, required joint fields
are checked, numbers must be finite, and implausible link lengths for the declared length unit are
refused. Errors are :class:`~hykin.kinematics.robot.RobotFileError` naming the file and the field.
Writing uses m and degrees for readability; only DH/MDH robots have a TOML form (URDF robots:
:func:`hykin.io.urdf.robot_to_urdf`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..geometry import se3
from ..kinematics.robot import Robot, RobotFileError

from .payload import MAX_PAYLOAD_KG
from .toml_compat import tomllib

__all__ = [
    "check_keys",
    "load_robot_toml",
    "robot_from_dict",
    "robot_from_toml_text",
    "robot_to_toml_string",
    "save_robot_toml",
]


def _get(tbl: dict, key: str, where: str, default=None, required: bool = False):
    if key in tbl:
        return tbl[key]
    if required:
        raise RobotFileError(f"{where}: missing required field '{key}'")
    return default


def _number(val, where: str) -> float:
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise RobotFileError(f"{where}: expected a number, got {val!r}")
    if not math.isfinite(val):
        raise RobotFileError(f"{where}: expected a finite number, got {val!r}")
    return float(val)


def _vec3(val, where: str) -> np.ndarray:
    if not isinstance(val, (list, tuple)) or len(val) != 3:
        raise RobotFileError(f"{where}: expected a list of 3 numbers, got {val!r}")
    return np.array([_number(v, where) for v in val])


def _frame(tbl: dict | None, where: str, L: float, A: float) -> np.ndarray:
    if tbl is None:
        return np.eye(4)
    if not isinstance(tbl, dict):
        raise RobotFileError(f"{where}: expected a table with xyz, rpy, got {tbl!r}")
    check_keys(tbl, ("xyz", "rpy"), where)
    xyz = _vec3(tbl.get("xyz", [0, 0, 0]), f"{where}.xyz") * L
    rpy = _vec3(tbl.get("rpy", [0, 0, 0]), f"{where}.rpy") * A
    return se3.xyzrpy_to_transform(xyz, rpy)


_JOINT_KEYS = ("a", "alpha", "d", "theta", "beta", "min", "max", "mass", "com", "stiffness", "type", "name")
_MAX_LIMIT_TURNS = 2.0  # a revolute limit beyond two turns either way (±720°) under angle_unit = 'rad': degrees
# Revolute limits that all lie within ±2π "degrees" (±6.2832, plus rounding of the last written digit)
# under angle_unit = 'deg' are radians: no arm's every joint turns by less than 6.3°. Only tested with at
# least _RAD_LIMITS_MIN_JOINTS revolute joints each spanning at least _RAD_LIMITS_MIN_SPAN (57° if
# radians), the shape of a real arm's limits written in radians; sub-degree test robots are left alone.
_RAD_LIMITS_AS_DEG = 2 * math.pi + 1e-3
_RAD_LIMITS_MIN_JOINTS = 4  # a tip/tilt/rotate stage or a gantry's head (3 rotary axes within a few degrees) is real
_RAD_LIMITS_MIN_SPAN = 1.0
_TOP_KEYS = ("name", "convention", "length_unit", "angle_unit", "joints", "tool", "base", "payload", "gravity", "source")
# Geometry a user must write for every joint: a silently defaulted link length or twist is a wrong
# robot. ``theta`` (the joint offset) and ``beta`` default to 0, the usual reading of a DH table
# without an offset column.
_REQUIRED_JOINT_KEYS = ("a", "alpha", "d", "min", "max")


def check_keys(tbl: dict, allowed, where: str) -> None:
    """Raise :class:`RobotFileError` for the first key of ``tbl`` not in ``allowed``, with a
    "did you mean" suggestion (closest allowed key, :mod:`difflib`)."""
    import difflib

    for k in tbl:
        if k not in allowed:
            close = difflib.get_close_matches(str(k), list(allowed), n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else f" (expected one of: {', '.join(allowed)})"
            raise RobotFileError(f"{where}: unknown key '{k}'{hint}")


def robot_from_dict(doc: dict, where: str = "<robot>") -> Robot:
    """Build a :class:`Robot` from a parsed robot-file dictionary (DESIGN.md §3).

    Strict: an unknown key at any level is an error with a "did you mean" suggestion (a typo such as
    ``lenght_unit`` must not silently fall back to metres); every joint needs ``a``, ``alpha``, ``d``,
    ``min`` and ``max``; ``theta`` (joint offset), ``beta``, mass properties and stiffness are optional.
    """
    check_keys(doc, _TOP_KEYS, f"{where}: top level")
    name = str(_get(doc, "name", where, default=Path(where).stem))
    convention = str(_get(doc, "convention", where, required=True)).lower()
    if convention not in ("dh", "mdh"):
        raise RobotFileError(f"{where}: convention must be 'dh' or 'mdh', got {convention!r}")
    lu = str(_get(doc, "length_unit", where, default="m"))
    au = str(_get(doc, "angle_unit", where, default="rad"))
    if lu not in ("m", "mm"):
        raise RobotFileError(f"{where}: length_unit must be 'm' or 'mm', got {lu!r}")
    if au not in ("deg", "rad"):
        raise RobotFileError(f"{where}: angle_unit must be 'deg' or 'rad', got {au!r}")
    L = 1e-3 if lu == "mm" else 1.0
    A = math.pi / 180 if au == "deg" else 1.0
    joints = _get(doc, "joints", where, required=True)
    if not isinstance(joints, list) or not joints:
        raise RobotFileError(f"{where}: 'joints' must be a non-empty array of tables ([[joints]])")
    cols: dict[str, list] = {k: [] for k in ("a", "alpha", "d", "theta", "beta", "min", "max", "mass", "stiffness")}
    com, types = [], []
    for i, j in enumerate(joints):
        w = f"{where}: joints[{i + 1}]"
        if not isinstance(j, dict):
            raise RobotFileError(f"{w}: expected a table ([[joints]]), got {j!r}")
        check_keys(j, _JOINT_KEYS, w)
        missing = [k for k in _REQUIRED_JOINT_KEYS if k not in j]
        if missing:
            raise RobotFileError(f"{w}: missing required field(s) {', '.join(repr(k) for k in missing)}"
                                 " (a, alpha, d, min, max are required; theta defaults to 0)")
        jt = str(j.get("type", "revolute"))
        if jt not in ("revolute", "prismatic"):
            raise RobotFileError(f"{w}.type: expected 'revolute' or 'prismatic', got {jt!r}")
        types.append(jt)
        for k in ("a", "d"):
            cols[k].append(_number(j.get(k, 0.0), f"{w}.{k}") * L)
        for k in ("alpha", "theta", "beta"):
            cols[k].append(_number(j.get(k, 0.0), f"{w}.{k}") * A)
        lim_scale = L if jt == "prismatic" else A
        for k in ("min", "max"):
            cols[k].append(_number(_get(j, k, w, required=True), f"{w}.{k}") * lim_scale)
        if cols["min"][-1] > cols["max"][-1]:
            raise RobotFileError(f"{w}: min = {j['min']} is above max = {j['max']} (swapped?)")
        cols["mass"].append(_number(j.get("mass", 0.0), f"{w}.mass"))
        if cols["mass"][-1] < 0:
            raise RobotFileError(f"{w}.mass: must be >= 0")
        com.append(_vec3(j.get("com", [0, 0, 0]), f"{w}.com") * L)
        k_ = _number(j.get("stiffness", math.inf), f"{w}.stiffness") if "stiffness" in j else math.inf
        if k_ <= 0:
            raise RobotFileError(f"{w}.stiffness: must be > 0 (N·m/rad)")
        cols["stiffness"].append(k_)
    # Link lengths in the wrong unit make a robot 1000x too large or small: no arm spans 30 m or 1 cm.
    tool_tbl = doc.get("tool") if isinstance(doc.get("tool"), dict) else {}
    tool_len = float(np.linalg.norm(_vec3(tool_tbl.get("xyz", [0, 0, 0]), f"{where}: [tool].xyz"))) * L
    size_m = float(np.sum(np.hypot(cols["a"], cols["d"]))) + tool_len
    if (lu == "m" and size_m > 30.0) or (lu == "mm" and 0.0 < size_m < 0.01):
        other = "mm" if lu == "m" else "m"
        raise RobotFileError(f"{where}: link lengths and tool add up to {size_m:.6g} m, implausible for a robot arm: "
                             f"the values look like {other} under length_unit = '{lu}' (set length_unit = '{other}')")
    # Twists and joint offsets in degrees under angle_unit = 'rad' read as dozens of turns: no DH
    # table needs a fixed angle beyond a full turn (a twist of 90 rad is 90 degrees written as rad).
    if au == "rad":
        fixed = np.abs(np.concatenate([cols["alpha"], cols["theta"], cols["beta"]]))
        if fixed.size and fixed.max() > 2 * math.pi + 1e-9:
            k = int(np.argmax(fixed)) % len(joints)
            raise RobotFileError(f"{where}: joints[{k + 1}]: a twist or joint offset of {fixed.max():.6g} rad (more than "
                                 f"a full turn) is implausible: the values look like degrees under angle_unit = 'rad' "
                                 f"(set angle_unit = 'deg')")
        rev = np.array([t == "revolute" for t in types])
        lim = np.abs(np.concatenate([np.asarray(cols["min"])[rev], np.asarray(cols["max"])[rev]]))
        if lim.size and lim.max() > _MAX_LIMIT_TURNS * 2 * math.pi:  # ±170 "rad" is 27 turns
            k = int(np.flatnonzero(rev)[int(np.argmax(lim)) % int(rev.sum())])
            raise RobotFileError(f"{where}: joints[{k + 1}]: a joint limit of {lim.max():.6g} rad ({lim.max() / (2 * math.pi):.3g} "
                                 f"turns) is implausible: the limits look like degrees under angle_unit = 'rad' (set "
                                 f"angle_unit = 'deg'; a joint that turns without end: type it continuous in a URDF)")
    if au == "deg":  # a fixed angle of exactly ±π/4 ... ±2π "degrees" is a radian value in a degree file
        rev_j = [i for i, t in enumerate(types) if t == "revolute"]
        fixed = np.degrees(np.concatenate([cols["alpha"], cols["theta"], cols["beta"], np.asarray(cols["min"])[rev_j],
                                           np.asarray(cols["max"])[rev_j]]))
        labels = ([f"joints[{i + 1}].{f}" for f in ("alpha", "theta", "beta") for i in range(len(joints))]
                  + [f"joints[{i + 1}].{f}" for f in ("min", "max") for i in rev_j])
        for frame in ("base", "tool"):
            rpy = doc.get(frame, {}).get("rpy") if isinstance(doc.get(frame), dict) else None
            if isinstance(rpy, list) and len(rpy) == 3 and all(isinstance(v, (int, float)) for v in rpy):
                fixed, labels = np.r_[fixed, np.asarray(rpy, dtype=np.float64)], labels + [f"[{frame}].rpy"] * 3
        quarter = np.abs(fixed) / (math.pi / 4)
        hit = (np.abs(fixed) > 0.5) & (np.abs(quarter - np.round(quarter)) < 1e-5) & (np.round(quarter) <= 8)
        if hit.any():
            k = int(np.flatnonzero(hit)[0])
            n4 = int(np.round(quarter[k]))
            frac = {1: "π/4", 2: "π/2", 3: "3π/4", 4: "π", 5: "5π/4", 6: "3π/2", 7: "7π/4", 8: "2π"}[n4]
            raise RobotFileError(f"{where}: {labels[k]}: {fixed[k]:.8g} deg is {'-' if fixed[k] < 0 else ''}{frac} to 1e-5: "
                                 f"a radian value under angle_unit = 'deg' (write it in degrees)")
    if au == "deg":
        _check_limits_not_radians(where, types, cols["min"], cols["max"])
    payload = _number(doc.get("payload", 0.0), f"{where}: payload")
    if not payload >= 0:
        raise RobotFileError(f"{where}: payload = {payload:g}: must be a mass >= 0 (kg)")
    if payload > MAX_PAYLOAD_KG:
        raise RobotFileError(f"{where}: payload = {payload:g} kg, more than any serial robot carries ({MAX_PAYLOAD_KG:g} kg): "
                             "grams? (payload is in kg)")
    gravity = _vec3(doc["gravity"], f"{where}: gravity") if "gravity" in doc else np.array([0.0, 0.0, -9.81])
    return Robot(
        name=name,
        convention=convention,
        a_m=cols["a"],
        alpha_rad=cols["alpha"],
        d_m=cols["d"],
        theta_rad=cols["theta"],
        beta_rad=cols["beta"],
        lower=cols["min"],
        upper=cols["max"],
        joint_type=tuple(types),
        mass_kg=cols["mass"],
        com_m=np.array(com),
        stiffness_nm_per_rad=cols["stiffness"],
        base=_frame(doc.get("base"), f"{where}: [base]", L, A),
        tool=_frame(doc.get("tool"), f"{where}: [tool]", L, A),
        payload_kg=payload,
        gravity_base=gravity,
        source=str(doc.get("source", "")),
    )


def _check_limits_not_radians(where: str, types, lower_rad, upper_rad) -> None:
    """Refuse revolute limits (rad, read from degrees) that all lie within ±2π degrees: radian values under
    angle_unit = 'deg' (±2.967 "deg" for ±170°), which would plan and calibrate a sliver of the workspace.
    Tested when at least 4 revolute joints each span at least 1 "degree" (module constants): an arm; a
    stage or a gantry head with 3 rotary axes of a few degrees is a real machine."""
    rev = [i for i, t in enumerate(types) if t == "revolute"]
    if len(rev) < _RAD_LIMITS_MIN_JOINTS:
        return
    lo, hi = np.degrees(np.asarray(lower_rad)[rev]), np.degrees(np.asarray(upper_rad)[rev])
    lim = np.abs(np.concatenate([lo, hi]))
    if lim.max() <= _RAD_LIMITS_AS_DEG and np.min(hi - lo) >= _RAD_LIMITS_MIN_SPAN:
        i = int(np.argmax(lim))
        key = f"joints[{rev[i % len(rev)] + 1}].{'min' if i < len(rev) else 'max'}"
        raise RobotFileError(f"{where}: {key}: every revolute joint limit lies within ±{2 * math.pi:.4f} "
                             f"(largest {lim.max():.6g} deg): the limits look like radians under angle_unit = 'deg' "
                             f"(write them in degrees, or set angle_unit = 'rad')")


def load_robot_toml(path: str | Path) -> Robot:
    """Load a TOML robot file (DESIGN.md §3). Errors name the file and the field."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RobotFileError(f"{path}: file not found") from None
    except UnicodeDecodeError as e:  # a binary file (a model, a spreadsheet) given as a robot file
        raise RobotFileError(f"{path}: not a TOML robot file (not UTF-8 text: byte {e.start} cannot be decoded)") from None
    return robot_from_toml_text(text, str(path))


def robot_from_toml_text(text: str, where: str) -> Robot:
    """Parse the text of a TOML robot file; ``where`` names the file (or preset) in errors."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise RobotFileError(f"{where}: invalid TOML: {e}") from None
    return robot_from_dict(doc, where)


def robot_to_toml_string(robot: Robot, length_unit: str = "m", angle_unit: str = "deg") -> str:
    """Serialise a DH/MDH robot to the TOML robot format, lengths in ``length_unit`` ("m" or "mm"),
    angles in ``angle_unit`` ("deg", the default for readability, or "rad")."""
    import tomli_w

    if length_unit not in ("m", "mm") or angle_unit not in ("deg", "rad"):
        raise RobotFileError(f"robot file units must be m/mm and deg/rad, got {length_unit!r}, {angle_unit!r}")
    L = 1e3 if length_unit == "mm" else 1.0
    deg = np.degrees if angle_unit == "deg" else (lambda x: x)

    if robot.convention not in ("dh", "mdh"):
        raise RobotFileError(f"robot {robot.name!r}: only DH/MDH robots can be saved as TOML (this one is {robot.convention})")
    joints = []
    for i in range(robot.dof):
        prism = robot.joint_type[i] == "prismatic"
        j = {
            "a": float(robot.a_m[i] * L),
            "alpha": float(deg(robot.alpha_rad[i])),
            "d": float(robot.d_m[i] * L),
            "theta": float(deg(robot.theta_rad[i])),
            # limits to 12 significant digits: -120 written as -120, not -119.99999999999999 (rad -> deg)
            "min": float(f"{float(robot.lower[i] * L if prism else deg(robot.lower[i])):.12g}"),
            "max": float(f"{float(robot.upper[i] * L if prism else deg(robot.upper[i])):.12g}"),
        }
        if robot.beta_rad[i] != 0:
            j["beta"] = float(deg(robot.beta_rad[i]))
        if prism:
            j["type"] = "prismatic"
        if robot.mass_kg[i] > 0:
            j["mass"] = float(robot.mass_kg[i])
            j["com"] = [float(v * L) for v in robot.com_m[i]]
        if np.isfinite(robot.stiffness_nm_per_rad[i]):
            j["stiffness"] = float(robot.stiffness_nm_per_rad[i])
        joints.append(j)

    def frame(T):
        xyz, rpy = se3.transform_to_xyzrpy(T)
        return {"xyz": [float(v * L) for v in xyz], "rpy": [float(v) for v in deg(rpy)]}

    doc = {
        "name": robot.name,
        "convention": robot.convention,
        "length_unit": length_unit,
        "angle_unit": angle_unit,
    }
    if robot.source:
        doc["source"] = robot.source
    if robot.payload_kg:
        doc["payload"] = robot.payload_kg
    if not np.allclose(robot.gravity_base, [0, 0, -9.81]):
        doc["gravity"] = [float(v) for v in robot.gravity_base]
    doc["joints"] = joints
    doc["tool"] = frame(robot.tool)
    doc["base"] = frame(robot.base)
    return tomli_w.dumps(doc)


def save_robot_toml(robot: Robot, path: str | Path) -> None:
    """Write ``robot`` as a TOML robot file."""
    Path(path).write_text(robot_to_toml_string(robot), encoding="utf-8")
