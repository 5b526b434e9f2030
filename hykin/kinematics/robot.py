"""Robot definitions: the :class:`Robot` dataclass, TOML robot files, presets, DH <-> MDH.

A robot is plain data: per-joint geometry arrays in SI units, limits, optional mass properties and
joint stiffness, plus base and tool transforms. Kinematics live in :mod:`hykin.chain`,
:mod:`hykin.fk` and :mod:`hykin.ik`.

Geometry conventions (``Robot.convention``):

* ``"dh"`` (standard, Denavit-Hartenberg): joint i contributes
  ``Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``; link frame i is the frame after it.
* ``"mdh"`` (modified, Craig): joint i contributes
  ``Rx(alpha_i) Tx(a_i) Ry(beta_i) Rz(theta_i + q_i) Tz(d_i)``; link frame i is the frame after it.
* ``"urdf"``: joint i contributes ``origin_i Rot(axis_i, q_i)`` (or ``Trans(axis_i q_i)`` for a
  prismatic joint); link frame i is the URDF child link frame.

``beta`` (Hayati's rotation about y) is zero in nominal models; calibration uses it for near-parallel
consecutive axes where DH is ill-conditioned. For prismatic joints in DH/MDH, ``q`` adds to ``d``.

World/measurement frame -> robot base is ``base``; flange (last link frame) -> TCP is ``tool``.
Gravity acts along ``gravity_base`` (m/s^2, in the robot base frame; default ``(0, 0, -9.81)``).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np

from . import se3

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "Robot",
    "RobotFileError",
    "check_keys",
    "dh_to_mdh",
    "list_presets",
    "load_robot",
    "load_robot_toml",
    "mdh_to_dh",
    "robot_to_toml_string",
    "save_robot_toml",
]

CONVENTIONS = ("dh", "mdh", "urdf")


class RobotFileError(ValueError):
    """A robot file (TOML or URDF) is malformed; the message names the file and the field."""


@dataclass
class Robot:
    """A serial robot: geometry, limits, mass properties, base and tool. All SI (m, rad, kg).

    Attributes
    ----------
    name: robot name.
    convention: ``"dh"``, ``"mdh"`` or ``"urdf"`` (see module docstring).
    a_m, alpha_rad, d_m, theta_rad, beta_rad: ``(n,)`` DH/MDH parameters (zeros for URDF robots).
    origin_xyz_m, origin_rpy_rad, axis: ``(n, 3)`` URDF joint origins and unit axes (URDF only).
    joint_type: ``(n,)`` strings ``"revolute"`` or ``"prismatic"``.
    lower, upper: ``(n,)`` joint limits (rad, or m for prismatic joints).
    mass_kg: ``(n,)`` link masses (zeros if unknown).
    com_m: ``(n, 3)`` centre of mass of link i in link frame i.
    stiffness_nm_per_rad: ``(n,)`` joint stiffness; ``inf`` = rigid.
    base: ``(4, 4)`` world/measurement frame -> robot base.
    tool: ``(4, 4)`` flange -> TCP.
    payload_kg: point mass at the TCP.
    gravity_base: ``(3,)`` gravity vector in the robot base frame, m/s^2.
    source: where the numbers come from (free text, kept in saved files).
    """

    name: str
    convention: str
    a_m: np.ndarray
    alpha_rad: np.ndarray
    d_m: np.ndarray
    theta_rad: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    beta_rad: np.ndarray | None = None
    origin_xyz_m: np.ndarray | None = None
    origin_rpy_rad: np.ndarray | None = None
    axis: np.ndarray | None = None
    joint_type: tuple[str, ...] | None = None
    mass_kg: np.ndarray | None = None
    com_m: np.ndarray | None = None
    stiffness_nm_per_rad: np.ndarray | None = None
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool: np.ndarray = field(default_factory=lambda: np.eye(4))
    payload_kg: float = 0.0
    gravity_base: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    source: str = ""

    def __post_init__(self) -> None:
        if self.convention not in CONVENTIONS:
            raise RobotFileError(f"robot {self.name!r}: convention must be one of {CONVENTIONS}, got {self.convention!r}")
        f = lambda x: np.array(x, dtype=np.float64, copy=True)
        self.a_m, self.alpha_rad, self.d_m, self.theta_rad = map(f, (self.a_m, self.alpha_rad, self.d_m, self.theta_rad))
        n = self.a_m.shape[0]
        for nm in ("alpha_rad", "d_m", "theta_rad"):
            if getattr(self, nm).shape != (n,):
                raise RobotFileError(f"robot {self.name!r}: {nm} has shape {getattr(self, nm).shape}, expected ({n},)")
        self.lower, self.upper = f(self.lower), f(self.upper)
        self.beta_rad = np.zeros(n) if self.beta_rad is None else f(self.beta_rad)
        self.origin_xyz_m = np.zeros((n, 3)) if self.origin_xyz_m is None else f(self.origin_xyz_m).reshape(n, 3)
        self.origin_rpy_rad = np.zeros((n, 3)) if self.origin_rpy_rad is None else f(self.origin_rpy_rad).reshape(n, 3)
        if self.axis is None:
            self.axis = np.tile([0.0, 0.0, 1.0], (n, 1))
        else:
            ax = f(self.axis).reshape(n, 3)
            self.axis = ax / np.linalg.norm(ax, axis=1, keepdims=True)
        self.joint_type = tuple(self.joint_type) if self.joint_type is not None else ("revolute",) * n
        if len(self.joint_type) != n or any(t not in ("revolute", "prismatic") for t in self.joint_type):
            raise RobotFileError(f"robot {self.name!r}: joint_type must be {n} of 'revolute'/'prismatic'")
        self.mass_kg = np.zeros(n) if self.mass_kg is None else f(self.mass_kg)
        self.com_m = np.zeros((n, 3)) if self.com_m is None else f(self.com_m).reshape(n, 3)
        self.stiffness_nm_per_rad = (
            np.full(n, np.inf) if self.stiffness_nm_per_rad is None else f(self.stiffness_nm_per_rad)
        )
        self.base, self.tool = f(self.base).reshape(4, 4), f(self.tool).reshape(4, 4)
        self.gravity_base = f(self.gravity_base).reshape(3)
        self.payload_kg = float(self.payload_kg)
        if np.any(self.lower > self.upper):
            j = int(np.argmax(self.lower > self.upper))
            raise RobotFileError(f"robot {self.name!r}: joint {j + 1} has min > max")

    @property
    def dof(self) -> int:
        """Number of joints."""
        return int(self.a_m.shape[0])

    @property
    def limits(self) -> np.ndarray:
        """``(n, 2)`` joint limits ``[lower, upper]``."""
        return np.stack([self.lower, self.upper], axis=1)

    @property
    def has_compliance(self) -> bool:
        """True when any joint has finite stiffness."""
        return bool(np.any(np.isfinite(self.stiffness_nm_per_rad)))

    def copy(self, **changes) -> Robot:
        """Deep copy with optional field changes (``dataclasses.replace`` semantics)."""
        new = replace(self, **changes)
        new.__post_init__()  # re-copies arrays so the copy shares no memory
        return new

    def random_joints(self, n: int, rng: np.random.Generator | int | None = None, margin: float = 0.0) -> np.ndarray:
        """``(n, dof)`` joints uniform within limits shrunk by ``margin`` (fraction of each range)."""
        rng = np.random.default_rng(rng)
        span = self.upper - self.lower
        lo, hi = self.lower + margin * span, self.upper - margin * span
        return lo + rng.random((n, self.dof)) * (hi - lo)

    def within_limits(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """``(N,)`` bool: every joint of each row within limits (with tolerance)."""
        q = np.atleast_2d(q)
        return np.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)


# --------------------------------------------------------------------------- TOML files


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
    payload = _number(doc.get("payload", 0.0), f"{where}: payload")
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


def load_robot_toml(path: str | Path) -> Robot:
    """Load a TOML robot file (DESIGN.md §3). Errors name the file and the field."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RobotFileError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise RobotFileError(f"{path}: invalid TOML: {e}") from None
    return robot_from_dict(doc, str(path))


def robot_to_toml_string(robot: Robot) -> str:
    """Serialise a DH/MDH robot to the TOML robot format (SI: m and deg for readability)."""
    import tomli_w

    if robot.convention not in ("dh", "mdh"):
        raise RobotFileError(f"robot {robot.name!r}: only DH/MDH robots can be saved as TOML (this one is {robot.convention})")
    deg = np.degrees
    joints = []
    for i in range(robot.dof):
        prism = robot.joint_type[i] == "prismatic"
        j = {
            "a": float(robot.a_m[i]),
            "alpha": float(deg(robot.alpha_rad[i])),
            "d": float(robot.d_m[i]),
            "theta": float(deg(robot.theta_rad[i])),
            "min": float(robot.lower[i] if prism else deg(robot.lower[i])),
            "max": float(robot.upper[i] if prism else deg(robot.upper[i])),
        }
        if robot.beta_rad[i] != 0:
            j["beta"] = float(deg(robot.beta_rad[i]))
        if prism:
            j["type"] = "prismatic"
        if robot.mass_kg[i] > 0:
            j["mass"] = float(robot.mass_kg[i])
            j["com"] = [float(v) for v in robot.com_m[i]]
        if np.isfinite(robot.stiffness_nm_per_rad[i]):
            j["stiffness"] = float(robot.stiffness_nm_per_rad[i])
        joints.append(j)

    def frame(T):
        xyz, rpy = se3.transform_to_xyzrpy(T)
        return {"xyz": [float(v) for v in xyz], "rpy": [float(v) for v in np.degrees(rpy)]}

    doc = {
        "name": robot.name,
        "convention": robot.convention,
        "length_unit": "m",
        "angle_unit": "deg",
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


def list_presets() -> list[str]:
    """Names of the robot presets shipped with hykin."""
    files = resources.files("hykin.presets").iterdir()
    return sorted(p.name[:-5] for p in files if p.name.endswith(".toml"))


def load_robot(spec: str | Path | Robot) -> Robot:
    """Load a robot from a preset name, a TOML robot file or a URDF file.

    URDF files take their chain from the first to the last link of the longest serial chain;
    use :func:`hykin.urdf.load_urdf` to name base and tip links explicitly.
    """
    if isinstance(spec, Robot):
        return spec
    s = str(spec)
    if s.lower() in list_presets():
        text = resources.files("hykin.presets").joinpath(s.lower() + ".toml").read_text(encoding="utf-8")
        return robot_from_dict(tomllib.loads(text), f"preset:{s.lower()}")
    p = Path(s)
    if p.suffix.lower() == ".urdf":
        from ..io.urdf import load_urdf

        return load_urdf(p)
    if p.suffix.lower() == ".toml" or p.exists():
        return load_robot_toml(p)
    raise RobotFileError(f"{s}: not a preset ({', '.join(list_presets())}), and no such file")


# --------------------------------------------------------------------------- DH <-> MDH


def dh_to_mdh(robot: Robot) -> Robot:
    """Exact conversion of a standard-DH robot to modified DH (same FK, same base/tool).

    Standard DH products ``Rz(θi)Tz(di)Tx(ai)Rx(αi)`` regroup as MDH joints with
    ``α'_i = α_{i-1}, a'_i = a_{i-1}`` (``α'_1 = a'_1 = 0``); the last ``Tx(a_n)Rx(α_n)`` moves into the
    tool. Mass properties are re-expressed in the new link frames. Requires ``beta == 0``.
    """
    if robot.convention != "dh":
        raise ValueError("dh_to_mdh: robot is not standard DH")
    if np.any(robot.beta_rad != 0):
        raise ValueError("dh_to_mdh: exact only for beta == 0")
    n = robot.dof
    a = np.concatenate([[0.0], robot.a_m[:-1]])
    al = np.concatenate([[0.0], robot.alpha_rad[:-1]])
    tail = se3.trans(robot.a_m[-1]) @ se3.rotx(robot.alpha_rad[-1])
    # Old link frame i = new frame i · Tx(a_i) Rx(α_i); COM maps through that transform.
    com = np.empty((n, 3))
    for i in range(n):
        Tfix = se3.trans(robot.a_m[i]) @ se3.rotx(robot.alpha_rad[i])
        com[i] = (Tfix @ np.append(robot.com_m[i], 1.0))[:3]
    return robot.copy(
        convention="mdh", a_m=a, alpha_rad=al, tool=tail @ robot.tool, com_m=com, name=robot.name
    )


def mdh_to_dh(robot: Robot) -> Robot:
    """Exact conversion of a modified-DH robot to standard DH (same FK, same base/tool).

    Inverse of :func:`dh_to_mdh`: ``a_i = a'_{i+1}, α_i = α'_{i+1}`` with the last pair zero, and the
    first ``Rx(α'_1)Tx(a'_1)`` moved into the base.
    """
    if robot.convention != "mdh":
        raise ValueError("mdh_to_dh: robot is not modified DH")
    if np.any(robot.beta_rad != 0):
        raise ValueError("mdh_to_dh: exact only for beta == 0")
    n = robot.dof
    a = np.concatenate([robot.a_m[1:], [0.0]])
    al = np.concatenate([robot.alpha_rad[1:], [0.0]])
    head = se3.rotx(robot.alpha_rad[0]) @ se3.trans(robot.a_m[0])
    com = np.empty((n, 3))
    for i in range(n):
        Tfix = se3.invert(se3.trans(a[i]) @ se3.rotx(al[i]))
        com[i] = (Tfix @ np.append(robot.com_m[i], 1.0))[:3]
    return robot.copy(convention="dh", a_m=a, alpha_rad=al, base=robot.base @ head, com_m=com, name=robot.name)
