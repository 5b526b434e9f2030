"""Parametric calibration: the "calibrated classical model" (DESIGN.md §1.4).

Identifies, from measured TCP poses (or positions), deviations of

* the geometry: per joint ``a, alpha, d, theta`` (DH / MDH) plus Hayati's ``beta`` where two
  consecutive axes are near-parallel (``|sin alpha| < 0.2``), or a small 6-D twist on every URDF
  joint origin (``o3.x`` ... ``o3.rz``);
* the base frame (world/measurement -> robot base) and the tool frame (flange -> TCP), each as a
  small 6-D twist applied on the right: ``T <- T · E(v, w)`` with ``E = [exp(w), v]``;
* joint compliance ``c_i = 1 / k_i`` (rad/N·m), the joints deflecting under the gravity torques of
  the link masses and payload (:mod:`hykin.compliance`): ``q_eff = q + c * tau(q_eff)``;

by Levenberg–Marquardt over all samples. The Jacobian is analytic and vectorised: every parameter is
an elementary twist (a rotation about, or a translation along, a known axis of a known frame of the
chain), so its column is ``[u x (p_tcp - p0); u]`` or ``[u; 0]`` evaluated at the deflected joints;
a compliance column is the joint's own column times its gravity torque (the small coupling
``c dtau/dq`` is left out of the Jacobian, not out of the residual: the fixed point is exact).
Each iteration relinearises at the current estimate (the deviations are composed into the robot),
so the Jacobian is always the exact derivative at zero deviation.

Residual per sample: ``p_meas - p_model`` (m) and, for full-pose data,
``w · log(R_meas R_model^T)`` (rad × ``w`` m/rad, the orientation weight).

Identifiability: the identification Jacobian is scaled by physical units (1 mm, 1 mrad,
1e-6 rad/N·m) and factorised by Householder QR in a fixed priority order (base, tool, joints
base-to-tip, compliance). ``|R_kk|`` is how much of column k is not explained by the columns before
it: a parameter whose ``|R_kk| / ‖column‖`` is below ``rank_tol`` (redundant, e.g. DH ``theta1`` and
``d1`` with a full base frame) or whose column is negligible (tool rotation for position-only data,
the compliance of a vertical joint 1) is fixed at zero. The check is repeated at the solution.
Standard deviations come from the sandwich covariance ``(JᵀJ)⁻¹ Jᵀ Σ J (JᵀJ)⁻¹`` with separate
residual variances for position and orientation rows (plain ``σ² (JᵀJ)⁻¹`` for one kind of row).
"""

from __future__ import annotations

import fnmatch
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.linalg

from . import se3
from .chain import build_chain
from .compliance import compliance_of, compliant_fk, deflected_joints, gravity_torques
from .fk import fk
from .robot import Robot

__all__ = [
    "CalibrationError",
    "CalibrationResult",
    "calibrate",
    "calibrated_fk",
    "parameter_names",
    "apply_deviations",
    "identification_jacobian",
]

SCALE_LENGTH_M = 1e-3  # typical deviation used to scale lengths (1 mm)
SCALE_ANGLE_RAD = 1e-3  # typical deviation used to scale angles (1 mrad)
SCALE_COMPLIANCE = 1e-6  # typical compliance, rad/N·m (k = 1e6 N·m/rad)
BETA_SIN_ALPHA = 0.2  # beta is added for joints whose |sin(alpha)| is below this (near-parallel axes)
_CHUNK = 20_000  # samples per Jacobian chunk (memory: ~6·P·chunk doubles)
_ID_SAMPLES = 600  # samples (evenly spread) used for the identifiability QR
_COARSE_SAMPLES = 20_000  # larger data sets first converge on this many evenly spread samples


def _gram(A: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """``Aᵀ B`` (``B = A`` by default) through torch: its thread pool degrades far less than
    OpenBLAS's on busy machines (measured 3-50x on 2 loaded cores)."""
    import torch

    a = torch.from_numpy(np.ascontiguousarray(A.T))  # (P, m)
    b = a if B is None else torch.from_numpy(np.ascontiguousarray(B.T))
    return (a @ b.T).numpy()


class CalibrationError(ValueError):
    """Bad input to :func:`calibrate` (shapes, non-finite values, unknown parameter names)."""


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class _Spec:
    name: str
    group: str  # "base" | "tool" | "geom" | "origin" | "comp"
    joint: int  # joint index (-1 for base/tool)
    field: str  # a alpha d theta beta | x y z rx ry rz | c
    unit: str  # "m" | "rad" | "c"


_TWIST = ("x", "y", "z", "rx", "ry", "rz")


def _candidate_specs(robot: Robot, *, base: bool, tool: bool, compliance: bool) -> list[_Spec]:
    """All candidate parameters in priority order (base, tool, joints, compliance)."""
    out: list[_Spec] = []
    tw = lambda g, j, prefix: [  # noqa: E731
        _Spec(f"{prefix}.{f}", g, j, f, "m" if f in ("x", "y", "z") else "rad") for f in _TWIST
    ]
    if base:
        out += tw("base", -1, "base")
    if tool:
        out += tw("tool", -1, "tool")
    n = robot.dof
    for i in range(n):
        k = i + 1
        if robot.convention == "urdf":
            out += tw("origin", i, f"o{k}")
            continue
        fields = ["a", "alpha", "d", "theta"]
        if abs(math.sin(robot.alpha_rad[i])) < BETA_SIN_ALPHA:
            fields.append("beta")
        for f in fields:
            out.append(_Spec(f"{f}{k}", "geom", i, f, "m" if f in ("a", "d") else "rad"))
    if compliance:
        for i in range(n):
            out.append(_Spec(f"c{i + 1}", "comp", i, "c", "c"))
    return out


def _scale_of(spec: _Spec) -> float:
    return {"m": SCALE_LENGTH_M, "rad": SCALE_ANGLE_RAD, "c": SCALE_COMPLIANCE}[spec.unit]


def parameter_names(robot: Robot, *, base: bool = True, tool: bool = True, compliance: bool = True) -> list[str]:
    """Names of the candidate calibration parameters of ``robot``, in priority order."""
    return [s.name for s in _candidate_specs(robot, base=base, tool=tool, compliance=compliance)]


def _select(specs: list[_Spec], params) -> list[_Spec]:
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


# --------------------------------------------------------------------------- data


def _as_data(robot: Robot, data, position_only):
    """-> q (N,n), xyz (N,3), R (N,3,3) or None."""
    if hasattr(data, "q") and hasattr(data, "xyz_m"):
        q, xyz = np.asarray(data.q, dtype=np.float64), np.asarray(data.xyz_m, dtype=np.float64)
        quat = getattr(data, "quat_wxyz", None)
        R = None if quat is None else se3.quat_to_matrix(np.asarray(quat, dtype=np.float64))
    elif isinstance(data, (tuple, list)) and len(data) == 2:
        q = np.asarray(data[0], dtype=np.float64)
        P = np.asarray(data[1], dtype=np.float64)
        if P.ndim == 3 and P.shape[1:] == (4, 4):
            xyz, R = P[:, :3, 3].copy(), P[:, :3, :3].copy()
        elif P.ndim == 2 and P.shape[1] == 3:
            xyz, R = P, None
        else:
            raise CalibrationError(f"data: measured poses must be (N, 4, 4) or positions (N, 3), got {P.shape}")
    else:
        raise CalibrationError("data: expected a Dataset or a tuple (q (N, n), poses (N, 4, 4) | positions (N, 3))")
    if q.ndim != 2 or q.shape[1] != robot.dof:
        raise CalibrationError(f"data: joints must be (N, {robot.dof}) for robot {robot.name!r}, got {q.shape}")
    if xyz.shape != (q.shape[0], 3):
        raise CalibrationError(f"data: positions must be ({q.shape[0]}, 3), got {xyz.shape}")
    for nm, arr in (("joints", q), ("positions", xyz)) + ((("orientations", R),) if R is not None else ()):
        bad = ~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1)
        if bad.any():
            raise CalibrationError(f"data: row {int(np.argmax(bad)) + 1}: non-finite {nm}")
    if position_only is None:
        position_only = R is None
    if position_only:
        R = None
    elif R is None:
        raise CalibrationError("data: position_only=False but the data have no orientations")
    return np.ascontiguousarray(q), xyz, R


# --------------------------------------------------------------------------- model state


@dataclass
class _State:
    """Current robot plus the compliance vector being identified."""

    robot: Robot
    c: np.ndarray  # (n,) compliance, rad/N·m


def _robot_with_c(robot: Robot, c: np.ndarray) -> Robot:
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


def _apply(state: _State, specs: list[_Spec], delta: np.ndarray) -> _State:
    """Compose the deviations ``delta`` (SI, one per spec) into a new state."""
    r = state.robot
    geom = {"a": r.a_m.copy(), "alpha": r.alpha_rad.copy(), "d": r.d_m.copy(), "theta": r.theta_rad.copy(), "beta": r.beta_rad.copy()}
    base6, tool6 = np.zeros(6), np.zeros(6)
    orig6 = np.zeros((r.dof, 6))
    c = state.c.copy()
    for s, v in zip(specs, delta):
        if s.group == "geom":
            geom[s.field][s.joint] += v
        elif s.group == "base":
            base6[_TWIST.index(s.field)] = v
        elif s.group == "tool":
            tool6[_TWIST.index(s.field)] = v
        elif s.group == "origin":
            orig6[s.joint, _TWIST.index(s.field)] = v
        else:
            c[s.joint] = max(c[s.joint] + v, 0.0)  # compliance is physical only when >= 0
    changes = dict(a_m=geom["a"], alpha_rad=geom["alpha"], d_m=geom["d"], theta_rad=geom["theta"], beta_rad=geom["beta"])
    changes["base"] = r.base @ _E(base6)
    changes["tool"] = r.tool @ _E(tool6)
    if r.convention == "urdf" and np.any(orig6):
        O = se3.xyzrpy_to_transform(r.origin_xyz_m, r.origin_rpy_rad)
        O = np.stack([O[i] @ _E(orig6[i]) for i in range(r.dof)])
        xyz, rpy = se3.transform_to_xyzrpy(O)
        changes.update(origin_xyz_m=xyz, origin_rpy_rad=rpy)
    new = _robot_with_c(r.copy(**changes), c)
    return _State(robot=new, c=c)


def apply_deviations(robot: Robot, deviations: dict[str, float]) -> Robot:
    """``robot`` with parameter deviations applied, in the parametrisation :func:`calibrate` reports.

    ``deviations``: ``{name: value}`` (SI) with names from :func:`parameter_names` (``"a2"``,
    ``"base.rz"``, ``"c3"``...). Base/tool/URDF-origin twists compose as ``T · E(x, y, z, rx, ry, rz)``
    (one 6-vector per frame); compliance adds to ``1 / stiffness``. Used to build test truths and to
    replay a :class:`CalibrationResult` (``apply_deviations(robot, dict(zip(res.names, res.values)))``).
    """
    specs = {s.name: s for s in _candidate_specs(robot, base=True, tool=True, compliance=True)}
    for name in ("beta",):  # beta is a candidate only for near-parallel axes; allow it everywhere here
        for i in range(robot.dof):
            specs.setdefault(f"{name}{i + 1}", _Spec(f"{name}{i + 1}", "geom", i, name, "rad"))
    unknown = [k for k in deviations if k not in specs]
    if unknown:
        raise CalibrationError(f"apply_deviations: unknown parameter(s) {', '.join(unknown)}")
    sel = [specs[k] for k in deviations]
    return _apply(_State(robot, compliance_of(robot)), sel, np.array([float(v) for v in deviations.values()])).robot


# --------------------------------------------------------------------------- model, residual, Jacobian


def _rmul(T: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``T @ M`` for a batch ``(N, 4, 4)`` and one ``(4, 4)`` (einsum: no BLAS thread start-up)."""
    return np.einsum("nij,jk->nik", T, M)


def _frames(chain, q: np.ndarray):
    """prev (N,n,4,4) frame before each joint's fixed part, joint (N,n,4,4) joint frames, tcp (N,4,4)."""
    N, n = q.shape
    prev = np.empty((N, n, 4, 4))
    joint = np.empty((N, n, 4, 4))
    T = np.broadcast_to(np.asarray(chain.base), (N, 4, 4)).copy()
    for i in range(n):
        prev[:, i] = T
        A = _rmul(T, np.asarray(chain.pre[i]))
        if chain.prismatic[i]:
            A[:, :3, 3] += A[:, :3, 2] * q[:, i : i + 1]
        else:
            cq, sq = np.cos(q[:, i])[:, None], np.sin(q[:, i])[:, None]
            x, y = A[:, :3, 0].copy(), A[:, :3, 1].copy()
            A[:, :3, 0] = cq * x + sq * y
            A[:, :3, 1] = cq * y - sq * x
        joint[:, i] = A
        T = _rmul(A, np.asarray(chain.post[i]))
    return prev, joint, _rmul(T, np.asarray(chain.tool))


def _model_poses(state: _State, q: np.ndarray) -> np.ndarray:
    return fk(state.robot, _effective_joints(state, q))


def _effective_joints(state: _State, q: np.ndarray) -> np.ndarray:
    """Deflected (link-side) joints under gravity, ``(N, n)`` (``q`` itself when rigid)."""
    if not np.any(state.c):
        return q
    return deflected_joints(state.robot, q, compliance=state.c)


def _rotation_residual(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """``log(R_a R_bᵀ)`` ``(N, 3)``: closed form (vectorised numpy) for angles below 3 rad, scipy
    for the rare rows near pi."""
    D = R_a @ np.swapaxes(R_b, -1, -2)
    v = 0.5 * np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], 1)
    s = np.linalg.norm(v, axis=1)
    c = 0.5 * (D[:, 0, 0] + D[:, 1, 1] + D[:, 2, 2] - 1.0)
    th = np.arctan2(s, c)
    small = th < 1e-6
    k = np.where(small, 1.0 + th * th / 6.0, th / np.where(small, 1.0, s))
    out = v * k[:, None]
    far = th > 3.0
    if far.any():
        out[far] = se3.matrix_to_rotvec(D[far])
    return out


def _residual(T_model: np.ndarray, xyz: np.ndarray, R_meas: np.ndarray | None, w: float):
    """(N, 3) position residual (m) and (N, 3) weighted rotation residual or None."""
    rp = xyz - T_model[:, :3, 3]
    ro = None if R_meas is None else w * _rotation_residual(R_meas, T_model[:, :3, :3])
    return rp, ro


def _local_axes(robot: Robot, spec: _Spec):
    """(frame kind, kind 'rot'|'trans', local axis (3,), local point (3,)) of a parameter."""
    e = np.eye(3)
    zero = np.zeros(3)
    i = spec.joint
    if spec.group in ("base", "tool", "origin"):
        frame = {"base": "base", "tool": "tcp", "origin": "origin"}[spec.group]
        j = _TWIST.index(spec.field)
        return (frame, "trans", e[j], zero) if j < 3 else (frame, "rot", e[j - 3], zero)
    if spec.group == "comp":
        return ("joint", "trans" if robot.joint_type[i] == "prismatic" else "rot", e[2], zero)
    prism = robot.joint_type[i] == "prismatic"
    al, a = robot.alpha_rad[i], robot.a_m[i]
    if robot.convention == "dh":
        d_post = 0.0 if prism else robot.d_m[i]
        return {
            "a": ("joint", "trans", e[0], zero),
            "alpha": ("joint", "rot", e[0], np.array([a, 0.0, d_post])),
            "d": ("joint", "trans", e[2], zero),
            "theta": ("joint", "rot", e[2], zero),
            "beta": ("joint", "rot", np.array([0.0, math.cos(al), math.sin(al)]), np.array([a, 0.0, d_post])),
        }[spec.field]
    return {  # mdh: alpha, a, beta act in the previous link frame
        "alpha": ("prev", "rot", e[0], zero),
        "a": ("prev", "trans", e[0], zero),
        "beta": ("prev", "rot", np.array([0.0, math.cos(al), math.sin(al)]), np.array([a, 0.0, 0.0])),
        "theta": ("joint", "rot", e[2], zero),
        "d": ("joint", "trans", e[2], zero),
    }[spec.field]


def _jacobian_chunk(state: _State, specs: list[_Spec], q_eff: np.ndarray, tau, w: float, with_rot: bool):
    """d(residual)/d(parameter) for one chunk, column-major: position rows ``(P, N, 3)`` and
    weighted rotation rows ``(P, N, 3)`` (or None), plus the modelled TCP poses ``(N, 4, 4)``."""
    robot = state.robot
    chain = build_chain(robot)
    prev, joint, tcp = _frames(chain, q_eff)
    p_tcp = tcp[:, :3, 3]
    N, P = q_eff.shape[0], len(specs)
    Jp = np.zeros((P, N, 3))
    Jo = np.zeros((P, N, 3)) if with_rot else None
    origin = None
    if robot.convention == "urdf" and any(s.group == "origin" for s in specs):
        O = se3.xyzrpy_to_transform(robot.origin_xyz_m, robot.origin_rpy_rad)
        origin = [_rmul(prev[:, i], O[i]) for i in range(robot.dof)]
    for k, s in enumerate(specs):
        frame, kind, u, pt = _local_axes(robot, s)
        if frame == "base":
            F = np.asarray(chain.base)[None]
        elif frame == "tcp":
            F = tcp
        elif frame == "joint":
            F = joint[:, s.joint]
        elif frame == "prev":
            F = prev[:, s.joint]
        else:
            F = origin[s.joint]
        R = F[:, :3, :3]
        uw = R[:, :, 0] * u[0] + R[:, :, 1] * u[1] + R[:, :, 2] * u[2]  # (N|1, 3) world axis
        t = None if s.group != "comp" else -tau[:, s.joint : s.joint + 1]
        if kind == "rot":
            p0 = R[:, :, 0] * pt[0] + R[:, :, 1] * pt[1] + R[:, :, 2] * pt[2] + F[:, :3, 3]
            r = p_tcp - p0
            ux, uy, uz = uw[:, 0:1], uw[:, 1:2], uw[:, 2:3]
            dp = np.concatenate([uy * r[:, 2:3] - uz * r[:, 1:2], uz * r[:, 0:1] - ux * r[:, 2:3],
                                 ux * r[:, 1:2] - uy * r[:, 0:1]], 1)
            Jp[k] = -dp if t is None else dp * t
            if with_rot:
                Jo[k] = -w * uw if t is None else w * uw * t
        else:
            Jp[k] = -uw if t is None else uw * t
    return Jp, Jo, tcp


def _linearize(state, specs, scale, q_eff_all, xyz, R_meas, w, chunk=_CHUNK, keep_rows=None):
    """Accumulate scaled normal equations over chunks (``q_eff_all``: deflected joints of ``state``).

    Returns dict with JtJ_p, JtJ_o (P,P), Jtr (P,), sse_p, sse_o, and (if keep_rows) the scaled
    Jacobian rows ``(rows, P)`` of the samples ``keep_rows``.
    """
    P = len(specs)
    with_rot = R_meas is not None
    out = {"JtJ_p": np.zeros((P, P)), "JtJ_o": np.zeros((P, P)), "Jtr": np.zeros(P), "sse_p": 0.0, "sse_o": 0.0}
    need_tau = any(s.group == "comp" for s in specs)
    kept = []
    sc = scale[:, None, None]
    for lo in range(0, q_eff_all.shape[0], chunk):
        sl = slice(lo, lo + chunk)
        q_eff = np.ascontiguousarray(q_eff_all[sl])
        tau = gravity_torques(state.robot, q_eff) if need_tau else None
        Jp, Jo, tcp = _jacobian_chunk(state, specs, q_eff, tau, w, with_rot)
        rp, ro = _residual(tcp, xyz[sl], None if R_meas is None else R_meas[sl], w)
        Jp *= sc
        Jp2 = Jp.reshape(P, -1)
        out["JtJ_p"] += _gram(Jp2.T)
        out["Jtr"] += Jp2 @ rp.reshape(-1)
        out["sse_p"] += float(np.sum(rp * rp))
        if with_rot:
            Jo *= sc
            Jo2 = Jo.reshape(P, -1)
            out["JtJ_o"] += _gram(Jo2.T)
            out["Jtr"] += Jo2 @ ro.reshape(-1)
            out["sse_o"] += float(np.sum(ro * ro))
        if keep_rows is not None:
            idx = keep_rows[(keep_rows >= lo) & (keep_rows < lo + q_eff.shape[0])] - lo
            if idx.size:
                rows = [Jp[:, idx].reshape(P, -1).T]
                if with_rot:
                    rows.append(Jo[:, idx].reshape(P, -1).T)
                kept.append(np.concatenate(rows, 0))
    if keep_rows is not None:
        out["J_id"] = np.concatenate(kept, 0) if kept else np.zeros((0, P))
    return out


def identification_jacobian(robot: Robot, q, *, position_only: bool = False, orientation_weight_m_per_rad: float = 1.0,
                            base: bool = True, tool: bool = True, compliance: bool = True):
    """Analytic identification Jacobian at ``robot`` for joints ``q`` ``(N, n)``.

    Returns ``(names, J)`` with ``J`` ``(N, 3 or 6, P)``: derivative of the modelled TCP position (m)
    and, unless ``position_only``, of ``w ·`` its rotation vector (world frame) with respect to each
    parameter deviation (SI units). Compliance columns are evaluated at the robot's own compliance.
    """
    specs = _candidate_specs(robot, base=base, tool=tool, compliance=compliance)
    q = np.ascontiguousarray(np.asarray(q, dtype=np.float64).reshape(-1, robot.dof))
    state = _State(robot=robot, c=compliance_of(robot))
    q_eff = _effective_joints(state, q)
    tau = gravity_torques(robot, np.ascontiguousarray(q_eff)) if compliance else None
    w = orientation_weight_m_per_rad
    Jp, Jo, _ = _jacobian_chunk(state, specs, np.ascontiguousarray(q_eff), tau, w, not position_only)
    J = -Jp if position_only else -np.concatenate([Jp, Jo], 2)
    return [s.name for s in specs], np.ascontiguousarray(J.transpose(1, 2, 0))


# --------------------------------------------------------------------------- identifiability


def _identifiable(J_s: np.ndarray, rank_tol: float, negligible_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Mask of identifiable columns of the scaled Jacobian (priority order) and the ratios |R_kk|/‖col‖."""
    norms = np.linalg.norm(J_s, axis=0)
    if J_s.shape[0] == 0 or not np.any(norms > 0):
        return np.zeros(J_s.shape[1], bool), np.zeros(J_s.shape[1])
    import torch

    R = torch.linalg.qr(torch.from_numpy(np.ascontiguousarray(J_s)), mode="r")[1].numpy()
    m = min(R.shape)
    rkk = np.zeros(J_s.shape[1])
    rkk[:m] = np.abs(np.diag(R[:m, :m]))
    ratio = np.where(norms > 0, rkk / np.where(norms > 0, norms, 1.0), 0.0)
    mask = (ratio > rank_tol) & (norms > negligible_tol * norms.max())
    return mask, ratio


def identifiable_columns(J_s: np.ndarray, rank_tol: float, negligible_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Public form of the identifiability check (used by :mod:`hykin.register`): ``J_s`` ``(rows, P)``
    scaled Jacobian with columns in priority order -> ``(mask (P,), |R_kk| / ‖col‖ (P,))``."""
    return _identifiable(J_s, rank_tol, negligible_tol)


# --------------------------------------------------------------------------- LM step


def _lm_step(lin: dict, act: np.ndarray, lam: float, is_comp: np.ndarray, c: np.ndarray, comp_joint: np.ndarray):
    """Damped Gauss-Newton step (scaled units) on the free parameters.

    Compliance is bounded below by 0: a compliance at its bound whose step points below it is held
    (active-set), then the system is solved again. Returns (free indices, step) or (.., None).
    """
    free = act.copy()
    while free.size:
        A = (lin["JtJ_p"] + lin["JtJ_o"])[np.ix_(free, free)]
        g = lin["Jtr"][free]
        D = np.sqrt(np.diag(A))
        D[D == 0] = 1.0
        M = A / np.outer(D, D) + lam * np.eye(free.size)
        try:
            step = -scipy.linalg.solve(M, g / D, assume_a="pos", check_finite=False) / D
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
            step = -np.linalg.lstsq(M, g / D, rcond=None)[0] / D
        held = is_comp[free] & (c[comp_joint[free]] <= 0) & (step < 0)
        if not held.any():
            return free, step
        free = free[~held]
    return free, None


# --------------------------------------------------------------------------- result


def _stats(rp: np.ndarray, ro: np.ndarray | None, w: float) -> dict:
    e = np.linalg.norm(rp, axis=1) * 1e3
    d = {
        "pos_mean_mm": float(e.mean()), "pos_rms_mm": float(np.sqrt(np.mean(e * e))),
        "pos_p95_mm": float(np.percentile(e, 95)), "pos_max_mm": float(e.max()),
    }
    if ro is not None:
        a = np.degrees(np.linalg.norm(ro, axis=1) / w)
        d.update({
            "rot_mean_deg": float(a.mean()), "rot_rms_deg": float(np.sqrt(np.mean(a * a))),
            "rot_p95_deg": float(np.percentile(a, 95)), "rot_max_deg": float(a.max()),
        })
    return d


@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate`.

    robot: the calibrated robot (geometry, base, tool, ``stiffness_nm_per_rad = 1 / c``).
    names: parameter names (priority order); values: identified deviations from the input robot
    (SI: m, rad, rad/N·m; base/tool/URDF-origin deviations as ``(x, y, z, rx, ry, rz)`` of
    ``T0⁻¹ T``); std: standard deviations (nan where not identified); identifiable: bool mask.
    correlation: ``(k, k)`` among the estimated parameters, ``correlation_names`` order (identifiable
    ones that did not end at a bound: a compliance at 0 has no std).
    strong_correlations: ``(name_i, name_j, rho)`` with ``|rho| > 0.9``.
    before / after: residual statistics on the calibration data (``pos_mean_mm``, ``pos_rms_mm``,
    ``pos_p95_mm``, ``pos_max_mm`` and the ``rot_*_deg`` twins for full-pose data).
    sigma_pos_m / sigma_rot_rad: residual standard deviations per coordinate after calibration.
    """

    robot: Robot
    names: list[str]
    values: np.ndarray
    std: np.ndarray
    identifiable: np.ndarray
    correlation: np.ndarray
    strong_correlations: list[tuple[str, str, float]]
    before: dict
    after: dict
    iterations: int
    converged: bool
    message: str
    units: list[str] = field(default_factory=list)
    correlation_names: list[str] = field(default_factory=list)
    n_samples: int = 0
    position_only: bool = False
    orientation_weight_m_per_rad: float = 1.0
    sigma_pos_m: float = float("nan")
    sigma_rot_rad: float = float("nan")
    seconds: float = 0.0

    @property
    def identified_names(self) -> list[str]:
        return [n for n, m in zip(self.names, self.identifiable) if m]

    @property
    def rms_before_mm(self) -> float:
        return self.before["pos_rms_mm"]

    @property
    def rms_after_mm(self) -> float:
        return self.after["pos_rms_mm"]

    def value(self, name: str) -> float:
        """Identified deviation of parameter ``name`` (SI)."""
        return float(self.values[self.names.index(name)])

    def report(self) -> str:
        """Human-readable table (lengths in mm, angles in deg, compliance in µrad/(N·m))."""
        lines = [
            f"Calibration of {self.robot.name!r}: {self.n_samples} samples, "
            f"{'position only' if self.position_only else f'full pose (w = {self.orientation_weight_m_per_rad:g} m/rad)'}, "
            f"{int(self.identifiable.sum())}/{len(self.names)} parameters identified, "
            f"{self.iterations} iterations, {'converged' if self.converged else 'NOT converged'} ({self.message}), "
            f"{self.seconds:.2f} s",
            f"{'parameter':<10} {'deviation':>14} {'std':>12}  unit",
        ]
        for n, v, s, u, m in zip(self.names, self.values, self.std, self.units, self.identifiable):
            f, un = {"m": (1e3, "mm"), "rad": (180 / math.pi, "deg"), "c": (1e6, "µrad/N·m")}[u]
            vs = f"{v * f:14.6f}" if m else f"{'fixed':>14}"
            ss = f"{s * f:12.6f}" if m and np.isfinite(s) else f"{'-':>12}"
            lines.append(f"{n:<10} {vs} {ss}  {un}")
        lines.append(f"{'':<10} {'before':>14} {'after':>12}")
        for key, lab in (("pos_mean_mm", "pos mean mm"), ("pos_p95_mm", "pos p95 mm"), ("pos_max_mm", "pos max mm"),
                         ("rot_mean_deg", "rot mean deg"), ("rot_p95_deg", "rot p95 deg"), ("rot_max_deg", "rot max deg")):
            if key in self.before:
                lines.append(f"{lab:<14} {self.before[key]:10.6f} {self.after[key]:12.6f}")
        if self.strong_correlations:
            lines.append("strong correlations (|rho| > 0.9): " + ", ".join(
                f"{a}~{b} {r:+.3f}" for a, b, r in self.strong_correlations))
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-able summary (SI units)."""
        f = lambda x: None if not np.isfinite(x) else float(x)  # noqa: E731
        return {
            "robot": self.robot.name,
            "n_samples": self.n_samples,
            "position_only": self.position_only,
            "orientation_weight_m_per_rad": self.orientation_weight_m_per_rad,
            "parameters": [
                {"name": n, "unit": u, "value": float(v), "std": f(s), "identifiable": bool(m)}
                for n, u, v, s, m in zip(self.names, self.units, self.values, self.std, self.identifiable)
            ],
            "identified_names": self.identified_names,
            "correlation_names": self.correlation_names,
            "correlation": self.correlation.tolist(),
            "strong_correlations": [[a, b, float(r)] for a, b, r in self.strong_correlations],
            "before": self.before,
            "after": self.after,
            "sigma_pos_m": f(self.sigma_pos_m),
            "sigma_rot_rad": f(self.sigma_rot_rad),
            "iterations": self.iterations,
            "converged": self.converged,
            "message": self.message,
            "seconds": self.seconds,
        }


# --------------------------------------------------------------------------- main entry


def calibrate(
    robot: Robot,
    data,
    *,
    params="auto",
    compliance: bool = True,
    base: bool = True,
    tool: bool = True,
    position_only: bool | None = None,
    orientation_weight_m_per_rad: float = 1.0,
    max_iter: int = 50,
    tol: float = 1e-12,
    rank_tol: float = 1e-6,
    negligible_tol: float = 1e-9,
    progress: Callable[[int, float], None] | None = None,
) -> CalibrationResult:
    """Identify geometry, base, tool and joint compliance of ``robot`` from measured poses.

    data: a :class:`hykin.dataset.Dataset` (or any object with ``q``, ``xyz_m``, ``quat_wxyz``), or a
    tuple ``(q (N, n) rad, poses (N, 4, 4) m)`` / ``(q, positions (N, 3) m)``. Measured poses are in
    the world/measurement frame (``robot.base`` maps it to the robot base).
    params: ``"auto"`` (every candidate, see :func:`parameter_names`) or fnmatch patterns selecting
    candidates (``["base.*", "tool.*"]`` re-registers a measurement series only).
    compliance/base/tool: include those parameter groups. position_only: ignore orientations
    (default: only when the data have none). orientation_weight_m_per_rad: length scale ``w`` that
    weights orientation residuals (1 m/rad: 1 mrad counts like 1 mm). max_iter / tol: LM iterations
    and relative cost decrease at which it stops. rank_tol: identifiability threshold on
    ``|R_kk| / ‖column‖``; negligible_tol: columns smaller than this times the largest are fixed.
    progress: called as ``progress(iteration, cost)``.
    """
    t0 = time.perf_counter()
    if not (orientation_weight_m_per_rad > 0 and math.isfinite(orientation_weight_m_per_rad)):
        raise CalibrationError(f"orientation_weight_m_per_rad must be a positive number, got {orientation_weight_m_per_rad}")
    q, xyz, R_meas = _as_data(robot, data, position_only)
    N = q.shape[0]
    if N == 0:
        raise CalibrationError("data: no samples")
    w = float(orientation_weight_m_per_rad)
    specs = _select(_candidate_specs(robot, base=base, tool=tool, compliance=compliance), params)
    P = len(specs)
    scale = np.array([_scale_of(s) for s in specs])
    state0 = _State(robot=robot.copy(), c=compliance_of(robot))
    rows_per = 3 if R_meas is None else 6
    is_comp = np.array([sp.group == "comp" for sp in specs])
    comp_joint = np.array([sp.joint for sp in specs])

    def cost_of(st: _State, qd, xyzd, Rd):
        q_eff = _effective_joints(st, qd)
        rp, ro = _residual(fk(st.robot, q_eff), xyzd, Rd, w)
        cost = 0.5 * (float(np.sum(rp * rp)) + (0.0 if ro is None else float(np.sum(ro * ro))))
        return cost, rp, ro, q_eff

    def run_lm(state, qd, xyzd, Rd, act, max_it, id_rows=None):
        """Relinearising LM on the samples ``qd``; returns (state, rp, ro, lin, it, converged, message)."""
        cost, rp, ro, q_eff = cost_of(state, qd, xyzd, Rd)
        lin = _linearize(state, specs, scale, q_eff, xyzd, Rd, w, keep_rows=id_rows)
        if act is None:
            return state, rp, ro, lin, 0, False, ""
        lam = 1e-6
        converged, message, it = False, "maximum number of iterations reached", 0
        if act.size == 0:
            return state, rp, ro, lin, 0, True, "no identifiable parameter"
        for it in range(1, max_it + 1):
            accepted = False
            for _ in range(12):
                free, step_s = _lm_step(lin, act, lam, is_comp, state.c, comp_joint)
                if step_s is None or np.max(np.abs(step_s)) < 1e-10:  # < 1e-13 m / rad: nothing left
                    converged, message = True, "step below 1e-13"
                    break
                delta = np.zeros(P)
                delta[free] = step_s * scale[free]
                trial = _apply(state, specs, delta)
                new_cost, new_rp, new_ro, new_q_eff = cost_of(trial, qd, xyzd, Rd)
                if new_cost < cost:
                    accepted = True
                    lam = max(lam / 10, 1e-12)
                    break
                lam *= 10
            if converged:
                break
            if not accepted:
                converged, message = True, "no further decrease of the cost"
                break
            rel = (cost - new_cost) / max(cost, 1e-300)
            state, cost, q_eff, rp, ro = trial, new_cost, new_q_eff, new_rp, new_ro
            if progress is not None:
                progress(it, cost)
            lin = _linearize(state, specs, scale, q_eff, xyzd, Rd, w, keep_rows=id_rows)
            if rel <= tol:
                converged, message = True, f"relative cost decrease {rel:.2g} <= tol"
                break
        return state, rp, ro, lin, it, converged, message

    # identifiability at the input robot, on evenly spread samples
    state = state0
    id_rows = np.unique(np.linspace(0, N - 1, min(N, _ID_SAMPLES)).astype(np.int64))
    sub = lambda a, idx: None if a is None else a[idx]  # noqa: E731
    _, rp0, ro0, lin0, _, _, _ = run_lm(state0, q[id_rows], xyz[id_rows], sub(R_meas, id_rows), None, 0,
                                        id_rows=np.arange(id_rows.size))
    mask, _ = _identifiable(lin0["J_id"], rank_tol, negligible_tol)
    if N * rows_per < mask.sum():
        raise CalibrationError(f"data: {N} samples give {N * rows_per} equations for {int(mask.sum())} parameters")
    act = np.flatnonzero(mask)
    it_sub = 0
    if N > 2 * _COARSE_SAMPLES:  # coarse-to-fine: converge on a spread subset, finish on all samples
        sel = np.unique(np.linspace(0, N - 1, _COARSE_SAMPLES).astype(np.int64))
        state, _, _, _, it_sub, _, _ = run_lm(state0, q[sel], xyz[sel], sub(R_meas, sel), act, max_iter)
    state, rp0, ro0, lin, it, converged, message = run_lm(
        state, q, xyz, R_meas, act, max(max_iter - it_sub, 1), id_rows=id_rows
    )
    it += it_sub
    before = _stats(*_residual(_model_poses(state0, q), xyz, R_meas, w), w)
    # recheck at the solution: the identified set must still have full rank there
    final = mask.copy()
    if act.size:
        keep_end, _ = _identifiable(lin["J_id"][:, act], rank_tol, negligible_tol)
        lost = [specs[k].name for k in act[~keep_end]]
        if lost:
            message += f"; at the solution {', '.join(lost)} became unidentifiable (no std reported)"
        final[act[~keep_end]] = False
    at_bound = final & is_comp & (state.c[np.maximum(comp_joint, 0)] <= 0)
    if at_bound.any():
        message += "; " + ", ".join(specs[k].name for k in np.flatnonzero(at_bound)) + " at the bound 0 (rigid; no std)"
    fa = np.flatnonzero(final & ~at_bound)
    rp, ro = rp0, ro0  # residuals of the accepted state
    after = _stats(rp, ro, w)
    m_p = rp.size
    m_o = 0 if ro is None else ro.size
    m = m_p + m_o
    dof_frac = max(m - fa.size, 1) / m
    sig2_p = float(np.sum(rp * rp)) / max(m_p * dof_frac, 1e-300)
    sig2_o = 0.0 if ro is None else float(np.sum(ro * ro)) / max(m_o * dof_frac, 1e-300)
    std = np.full(P, np.nan)
    corr = np.zeros((fa.size, fa.size))
    strong: list[tuple[str, str, float]] = []
    if fa.size:
        Jp = lin["JtJ_p"][np.ix_(fa, fa)]
        Jo = lin["JtJ_o"][np.ix_(fa, fa)]
        A = Jp + Jo
        D = np.sqrt(np.diag(A))
        Ainv = np.linalg.pinv(A / np.outer(D, D), rcond=1e-15) / np.outer(D, D)
        cov_s = Ainv @ (sig2_p * Jp + sig2_o * Jo) @ Ainv
        sd_s = np.sqrt(np.clip(np.diag(cov_s), 0, None))
        std[fa] = sd_s * scale[fa]
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov_s / np.outer(sd_s, sd_s)
        corr = np.nan_to_num(corr)
        for a_ in range(fa.size):
            for b_ in range(a_ + 1, fa.size):
                if abs(corr[a_, b_]) > 0.9:
                    strong.append((specs[fa[a_]].name, specs[fa[b_]].name, float(corr[a_, b_])))
    values = _deviations(state0, state, specs)
    return CalibrationResult(
        robot=state.robot, names=[s.name for s in specs], values=values, std=std, identifiable=final,
        correlation=corr, strong_correlations=strong, before=before, after=after, iterations=it,
        converged=converged, message=message, units=[s.unit for s in specs], n_samples=N,
        correlation_names=[specs[k].name for k in fa],
        position_only=R_meas is None, orientation_weight_m_per_rad=w, sigma_pos_m=math.sqrt(sig2_p),
        sigma_rot_rad=math.sqrt(sig2_o) / w if R_meas is not None else float("nan"),
        seconds=time.perf_counter() - t0,
    )


def _deviations(s0: _State, s1: _State, specs: Sequence[_Spec]) -> np.ndarray:
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
            out[k] = b[_TWIST.index(s.field)]
        elif s.group == "tool":
            out[k] = t[_TWIST.index(s.field)]
        elif s.group == "origin":
            out[k] = _log6(np.linalg.inv(O0[s.joint]) @ O1[s.joint])[_TWIST.index(s.field)]
        else:
            out[k] = s1.c[s.joint] - s0.c[s.joint]
    return out


def calibrated_fk(robot: Robot, q) -> np.ndarray:
    """Prediction of the calibrated classical model: TCP poses ``(N, 4, 4)`` including joint
    compliance under gravity (:func:`hykin.compliance.compliant_fk`)."""
    return compliant_fk(robot, q)
