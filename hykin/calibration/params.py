"""Calibration parameters and the model state they act on (used by :mod:`hykin.calibration.calibrate`).

A parameter is a :class:`ParamSpec` (group, joint, field, unit): per-joint geometry (a, alpha, d, theta,
and beta where consecutive axes are near-parallel), base and tool frames (a 6-twist each), the joint
origins of URDF chains, further reflector points, joint compliances, and the frames of further
stations and tools (``station[B].x`` ..., ``tool[T2].x`` ...; :mod:`hykin.calibration.stations`). :class:`ModelState` is a
robot plus its compliances and reflector offsets; :func:`apply_step` applies a deviation vector to it
and :func:`deviations_between` measures one between two states, both in SI units (m, rad, rad/N·m).
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3
from ..kinematics.compliance import compliance_of
from ..kinematics.robot import Robot
from .result import CalibrationError
from .stations import StationFrames

__all__ = [
    "BETA_SIN_ALPHA",
    "SCALE_ANGLE_RAD",
    "SCALE_COMPLIANCE",
    "SCALE_LENGTH_M",
    "TWIST",
    "ModelState",
    "ParamSpec",
    "apply_deviations",
    "apply_step",
    "candidate_specs",
    "deviations_between",
    "parameter_names",
    "robot_with_compliance",
    "scale_of",
    "select_specs",
]

SCALE_LENGTH_M = 1e-3  # typical deviation used to scale lengths (1 mm)
SCALE_ANGLE_RAD = 1e-3  # typical deviation used to scale angles (1 mrad)
SCALE_COMPLIANCE = 1e-6  # typical compliance, rad/N·m (k = 1e6 N·m/rad)
BETA_SIN_ALPHA = 0.2  # beta is added for joints whose |sin(alpha)| is below this (near-parallel axes)

# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class ParamSpec:
    name: str
    group: str  # "base" | "tool" | "geom" | "origin" | "comp" | "point" | "station" | "tools"
    joint: int  # joint index (-1 for base/tool; station / tool index for "station" / "tools")
    field: str  # a alpha d theta beta | x y z rx ry rz | c
    unit: str  # "m" | "rad" | "c"


TWIST = ("x", "y", "z", "rx", "ry", "rz")


def candidate_specs(robot: Robot, *, base: bool, tool: bool, compliance: bool, n_points: int = 1,
                    stations: Sequence[str] = (), tools: Sequence[str] = ()) -> list[ParamSpec]:
    """All candidate parameters in priority order (base, tool, further stations' and tools' frames,
    joints, compliance, further reflectors' offsets ``p2.x`` ... in the TCP frame when ``n_points > 1``).
    ``stations`` / ``tools``: labels of the stations / tools after the reference (index 1, 2, ...)."""
    out: list[ParamSpec] = []
    tw = lambda g, j, prefix: [
        ParamSpec(f"{prefix}.{f}", g, j, f, "m" if f in ("x", "y", "z") else "rad") for f in TWIST
    ]
    if base:
        out += tw("base", -1, "base")
    if tool:
        out += tw("tool", -1, "tool")
    for k, lab in enumerate(stations, start=1):
        out += tw("station", k, f"station[{lab}]")
    for k, lab in enumerate(tools, start=1):
        out += tw("tools", k, f"tool[{lab}]")
    n = robot.n_chain  # per chain joint (a mimic joint's origin is calibrated like any other)
    for i in range(n):
        k = i + 1
        if robot.convention == "urdf":
            out += tw("origin", i, f"o{k}")
            continue
        fields = ["a", "alpha", "d", "theta"]
        if abs(math.sin(robot.alpha_rad[i])) < BETA_SIN_ALPHA:
            fields.append("beta")
        for f in fields:
            out.append(ParamSpec(f"{f}{k}", "geom", i, f, "m" if f in ("a", "d") else "rad"))
    if compliance:
        for i in range(n):
            out.append(ParamSpec(f"c{i + 1}", "comp", i, "c", "c"))
    for k in range(1, n_points):
        out += [ParamSpec(f"p{k + 1}.{f}", "point", k, f, "m") for f in ("x", "y", "z")]
    return out


def scale_of(spec: ParamSpec) -> float:
    return {"m": SCALE_LENGTH_M, "rad": SCALE_ANGLE_RAD, "c": SCALE_COMPLIANCE}[spec.unit]


def parameter_names(robot: Robot, *, base: bool = True, tool: bool = True, compliance: bool = True) -> list[str]:
    """Names of the candidate calibration parameters of ``robot``, in priority order."""
    return [s.name for s in candidate_specs(robot, base=base, tool=tool, compliance=compliance)]


def select_specs(specs: list[ParamSpec], params) -> list[ParamSpec]:
    if params is None or (isinstance(params, str) and params == "auto"):
        return specs
    pats = [params] if isinstance(params, str) else list(params)
    keep = [s for s in specs if any(fnmatch.fnmatchcase(s.name, p) for p in pats)]
    for p in pats:
        if not any(fnmatch.fnmatchcase(s.name, p) for s in specs):
            raise CalibrationError(
                f"params: pattern {p!r} matches no parameter; candidates are {', '.join(s.name for s in specs)}"
            )
    return keep


# --------------------------------------------------------------------------- model state


@dataclass
class ModelState:
    """Current robot plus the compliance vector being identified."""

    robot: Robot
    c: np.ndarray  # (n,) compliance, rad/N·m
    pts: np.ndarray = field(default_factory=lambda: np.zeros((1, 3)))  # (K, 3) reflector offsets, TCP frame; row 0 = 0
    frames: StationFrames | None = None  # several stations / tools: every frame (index 0 = robot base / tool)


def robot_with_compliance(robot: Robot, c: np.ndarray) -> Robot:
    k = np.where(c > 0, 1.0 / np.where(c > 0, c, 1.0), np.inf)
    return robot.copy(stiffness_nm_per_rad=k)


def _E(v: np.ndarray) -> np.ndarray:
    """``[exp(w), t]`` from a 6-vector ``(t, w)``."""
    T = np.eye(4)
    T[:3, :3] = se3.rotvec_to_matrix(np.asarray(v[3:], dtype=np.float64))
    T[:3, 3] = v[:3]
    return T


def _log6(T: np.ndarray) -> np.ndarray:
    return np.concatenate([T[:3, 3], se3.matrix_to_rotvec(T[:3, :3])])


def apply_step(state: ModelState, specs: list[ParamSpec], delta: np.ndarray) -> ModelState:
    """Compose the deviations ``delta`` (SI, one per spec) into a new state."""
    r = state.robot
    geom = {"a": r.a_m.copy(), "alpha": r.alpha_rad.copy(), "d": r.d_m.copy(), "theta": r.theta_rad.copy(), "beta": r.beta_rad.copy()}
    base6, tool6 = np.zeros(6), np.zeros(6)
    orig6 = np.zeros((r.n_chain, 6))
    c = state.c.copy()
    pts = state.pts.copy()
    fr = None if state.frames is None else state.frames.copy()
    st6 = {"station": {}, "tools": {}}
    for s, v in zip(specs, delta):
        if s.group in st6:
            st6[s.group].setdefault(s.joint, np.zeros(6))[TWIST.index(s.field)] = v
        elif s.group == "point":
            pts[s.joint, TWIST.index(s.field)] += v
        elif s.group == "geom":
            geom[s.field][s.joint] += v
        elif s.group == "base":
            base6[TWIST.index(s.field)] = v
        elif s.group == "tool":
            tool6[TWIST.index(s.field)] = v
        elif s.group == "origin":
            orig6[s.joint, TWIST.index(s.field)] = v
        else:
            c[s.joint] = max(c[s.joint] + v, 0.0)  # compliance is physical only when >= 0
    for k, v in st6["station"].items():
        fr.station_bases[k] = fr.station_bases[k] @ _E(v)
    for k, v in st6["tools"].items():
        fr.tool_frames[k] = fr.tool_frames[k] @ _E(v)
    changes = dict(a_m=geom["a"], alpha_rad=geom["alpha"], d_m=geom["d"], theta_rad=geom["theta"], beta_rad=geom["beta"])
    changes["base"] = r.base @ _E(base6)
    changes["tool"] = r.tool @ _E(tool6)
    if r.convention == "urdf" and np.any(orig6):
        O = se3.xyzrpy_to_transform(r.origin_xyz_m, r.origin_rpy_rad)
        O = np.stack([O[i] @ _E(orig6[i]) for i in range(r.n_chain)])
        xyz, rpy = se3.transform_to_xyzrpy(O)
        changes.update(origin_xyz_m=xyz, origin_rpy_rad=rpy)
    new = robot_with_compliance(r.copy(**changes), c)
    return ModelState(robot=new, c=c, pts=pts, frames=None if fr is None else fr.synced(new))



def apply_deviations(robot: Robot, deviations: dict[str, float]) -> Robot:
    """``robot`` with parameter deviations applied, in the parametrisation :func:`calibrate` reports.

    ``deviations``: ``{name: value}`` (SI) with names from :func:`parameter_names` (``"a2"``,
    ``"base.rz"``, ``"c3"``...). Base/tool/URDF-origin twists compose as ``T · E(x, y, z, rx, ry, rz)``
    (one 6-vector per frame); compliance adds to ``1 / stiffness``. Used to build test truths and to
    replay a :class:`CalibrationResult` (``apply_deviations(robot, dict(zip(res.names, res.values)))``).
    """
    specs = {s.name: s for s in candidate_specs(robot, base=True, tool=True, compliance=True)}
    for name in ("beta",):  # beta is a candidate only for near-parallel axes; allow it everywhere here
        for i in range(robot.n_chain):
            specs.setdefault(f"{name}{i + 1}", ParamSpec(f"{name}{i + 1}", "geom", i, name, "rad"))
    unknown = [k for k in deviations if k not in specs]
    if unknown:
        raise CalibrationError(f"apply_deviations: unknown parameter(s) {', '.join(unknown)}")
    sel = [specs[k] for k in deviations]
    return apply_step(ModelState(robot, compliance_of(robot)), sel, np.array([float(v) for v in deviations.values()])).robot



def deviations_between(s0: ModelState, s1: ModelState, specs: Sequence[ParamSpec]) -> np.ndarray:
    r0, r1 = s0.robot, s1.robot
    b = _log6(np.linalg.inv(r0.base) @ r1.base)
    t = _log6(np.linalg.inv(r0.tool) @ r1.tool)
    O0 = se3.xyzrpy_to_transform(r0.origin_xyz_m, r0.origin_rpy_rad)
    O1 = se3.xyzrpy_to_transform(r1.origin_xyz_m, r1.origin_rpy_rad)
    geo = {"a": "a_m", "alpha": "alpha_rad", "d": "d_m", "theta": "theta_rad", "beta": "beta_rad"}
    out = np.zeros(len(specs))
    for k, s in enumerate(specs):
        if s.group == "geom":
            out[k] = getattr(r1, geo[s.field])[s.joint] - getattr(r0, geo[s.field])[s.joint]
        elif s.group == "base":
            out[k] = b[TWIST.index(s.field)]
        elif s.group == "tool":
            out[k] = t[TWIST.index(s.field)]
        elif s.group == "origin":
            out[k] = _log6(np.linalg.inv(O0[s.joint]) @ O1[s.joint])[TWIST.index(s.field)]
        elif s.group in ("station", "tools"):
            F0, F1 = ((s0.frames.station_bases, s1.frames.station_bases) if s.group == "station"
                      else (s0.frames.tool_frames, s1.frames.tool_frames))
            out[k] = _log6(np.linalg.inv(F0[s.joint]) @ F1[s.joint])[TWIST.index(s.field)]
        elif s.group == "point":
            out[k] = s1.pts[s.joint, TWIST.index(s.field)] - s0.pts[s.joint, TWIST.index(s.field)]
        else:
            out[k] = s1.c[s.joint] - s0.c[s.joint]
    return out
