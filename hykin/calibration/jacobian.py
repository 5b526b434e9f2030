"""The calibration's model of the measurements and its identification Jacobian (used by
:mod:`hykin.calibration.calibrate`, :mod:`hykin.planning` and :mod:`hykin.measure.register` through ``calibrate``).

:func:`model_poses` / :func:`effective_joints`: TCP poses and deflected joints of a
:class:`~hykin.calibration.params.ModelState` (per-row payloads through :mod:`hykin.io.payload`);
:func:`residual`: stacked position (every reflector) and weighted orientation residuals;
:func:`jacobian_chunk` / :func:`linearize`: analytic derivatives with respect to every
:class:`~hykin.calibration.params.ParamSpec`, accumulated as scaled normal equations in chunks;
:func:`identification_jacobian`: the same Jacobian for one robot and joint set (SI units).

Several stations / tools (``groups``, :mod:`hykin.calibration.stations`): each row's pose is
``L · T_ref · Rt``; the Jacobian is computed in the reference frame at the row's own TCP and rotated by
``L``; a frame's columns (``base``, ``station[..]``, ``tool``, ``tool[..]``) act on its own rows only.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import se3
from ..io.payload import payload_kwargs
from ..kinematics.chain import build_chain
from ..kinematics.compliance import compliance_of, deflected_joints, gravity_torques
from ..kinematics.fk import fk
from ..kinematics.robot import Robot
from ..kinematics.walk import chain_walk
from .params import TWIST, ModelState, ParamSpec, candidate_specs
from .stations import apply_row_transforms, row_transforms

__all__ = [
    "CHUNK",
    "effective_joints",
    "gram",
    "identification_jacobian",
    "jacobian_chunk",
    "linearize",
    "model_poses",
    "residual",
]

CHUNK = 20_000  # samples per Jacobian chunk (memory: ~6·P·chunk doubles)


def gram(A: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """``Aᵀ B`` (``B = A`` by default) through torch: its thread pool degrades far less than
    OpenBLAS's on busy machines (measured 3-50x on 2 loaded cores)."""
    import torch

    a = torch.from_numpy(np.ascontiguousarray(A.T))  # (P, m)
    b = a if B is None else torch.from_numpy(np.ascontiguousarray(B.T))
    return (a @ b.T).numpy()



# --------------------------------------------------------------------------- model, residual, Jacobian


def _rmul(T: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``T @ M`` for a batch ``(N, 4, 4)`` and one ``(4, 4)`` (einsum: no BLAS thread start-up)."""
    return np.einsum("nij,jk->nik", T, M)


def _frames(chain, q: np.ndarray):
    """prev (N,n,4,4) frame before each joint's fixed part ``pre_i``, joint (N,n,4,4) joint frames,
    tcp (N,4,4): the one chain walk (:func:`hykin.kinematics.walk.chain_walk`) with its frames."""
    joint, link, tcp = chain_walk(np, chain, q, frames=True)
    base = np.broadcast_to(np.asarray(chain.base), (len(q), 1, 4, 4))
    return np.concatenate([base, link[:, :-1]], 1), joint, tcp


def model_poses(state: ModelState, q: np.ndarray, payload=None, groups=None) -> np.ndarray:
    """Modelled TCP poses ``(N, 4, 4)``, each row in its own station's frame with its own tool when
    ``groups`` (:class:`~hykin.calibration.stations.RowGroups` of these rows) is given."""
    return framed(state, fk(state.robot, effective_joints(state, q, payload)), groups)


def framed(state: ModelState, T: np.ndarray, groups) -> np.ndarray:
    """Reference-frame poses ``T`` ``(N, 4, 4)`` in each row's station frame with its tool (``groups``; None: ``T``)."""
    if groups is None or state.frames is None:
        return T
    return apply_row_transforms(T, *row_transforms(state.frames, groups))


def effective_joints(state: ModelState, q: np.ndarray, payload=None) -> np.ndarray:
    """Deflected (link-side) joints under gravity, ``(N, n)`` (``q`` itself when rigid); ``payload``:
    per-row ``(kg (N,), com (N, 3) | None)`` or None (the robot's payload)."""
    if not np.any(state.c):
        return q
    return deflected_joints(state.robot, q, compliance=state.c, **payload_kwargs(payload))


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


def _points_of(T_model: np.ndarray, pts: np.ndarray | None) -> np.ndarray:
    """Modelled reflector positions ``(N, K, 3)``: TCP ``T_model`` plus offsets ``pts`` ``(K, 3)`` (TCP frame)."""
    if pts is None or len(pts) == 1 and not np.any(pts):
        return T_model[:, None, :3, 3]
    return T_model[:, None, :3, 3] + np.einsum("nij,kj->nki", T_model[:, :3, :3], pts)


def residual(T_model: np.ndarray, xyz: np.ndarray, R_meas: np.ndarray | None, w: float, pts: np.ndarray | None = None):
    """Position residual (m) ``(N·K, 3)`` (sample-major, ``K`` reflectors; ``(N, 3)`` for ``xyz``
    ``(N, 3)``) and ``(N, 3)`` weighted rotation residual or None."""
    if xyz.ndim == 3:
        rp = (xyz - _points_of(T_model, pts)).reshape(-1, 3)
    else:
        rp = xyz - T_model[:, :3, 3]
    ro = None if R_meas is None else w * _rotation_residual(R_meas, T_model[:, :3, :3])
    return rp, ro


def _local_axes(robot: Robot, spec: ParamSpec):
    """(frame kind, kind 'rot'|'trans', local axis (3,), local point (3,)) of a parameter."""
    e = np.eye(3)
    zero = np.zeros(3)
    i = spec.joint
    if spec.group in ("base", "tool", "origin", "station", "tools"):
        frame = {"base": "base", "tool": "tcp", "origin": "origin", "station": "base", "tools": "tcp"}[spec.group]
        j = TWIST.index(spec.field)
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


def jacobian_chunk(state: ModelState, specs: list[ParamSpec], q_eff: np.ndarray, tau, w: float, with_rot: bool,
                   groups=None):
    """d(residual)/d(parameter) for one chunk, column-major: position rows ``(P, N, 3)`` and
    weighted rotation rows ``(P, N, 3)`` (or None), plus the modelled TCP poses ``(N, 4, 4)``.
    ``groups``: the rows' stations and tools (module docstring) or None."""
    robot = state.robot
    chain = build_chain(robot)
    prev, joint, tcp = _frames(chain, q_eff)
    L = Rt = None
    if groups is not None and state.frames is not None:
        L, Rt = row_transforms(state.frames, groups)
        if Rt is not None:
            tcp = tcp @ Rt  # each row's own TCP, reference frame
    p_tcp = _points_of(tcp, state.pts)  # (N, K, 3)
    N, P, K = q_eff.shape[0], len(specs), p_tcp.shape[1]
    Jp = np.zeros((P, N, K, 3))
    Jo = np.zeros((P, N, 3)) if with_rot else None
    origin = None
    if robot.convention == "urdf" and any(s.group == "origin" for s in specs):
        O = se3.xyzrpy_to_transform(robot.origin_xyz_m, robot.origin_rpy_rad)
        origin = [_rmul(prev[:, i], O[i]) for i in range(robot.n_chain)]
    for k, s in enumerate(specs):
        if s.group == "point":  # a further reflector's offset along a TCP axis: moves that point only
            Jp[k, :, s.joint] = -tcp[:, :3, TWIST.index(s.field)]
            continue
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
            r = p_tcp - p0[:, None, :]  # (N, K, 3)
            ux, uy, uz = uw[:, None, 0:1], uw[:, None, 1:2], uw[:, None, 2:3]
            dp = np.concatenate([uy * r[..., 2:3] - uz * r[..., 1:2], uz * r[..., 0:1] - ux * r[..., 2:3],
                                 ux * r[..., 1:2] - uy * r[..., 0:1]], -1)
            Jp[k] = -dp if t is None else dp * t[:, :, None]
            if with_rot:
                Jo[k] = -w * uw if t is None else w * uw * t
        else:
            Jp[k] = -uw[:, None, :] if t is None else uw[:, None, :] * t[:, :, None]
        own = None if L is None and Rt is None else _own_rows(s, groups)
        if own is not None:
            Jp[k, ~own] = 0.0
            if with_rot:
                Jo[k, ~own] = 0.0
    if L is not None:  # into each row's station frame
        RL = L[:, :3, :3]
        Jp = np.einsum("nij,pnkj->pnki", RL, Jp)
        if with_rot:
            Jo = np.einsum("nij,pnj->pni", RL, Jo)
        tcp = L @ tcp
    return Jp, Jo, tcp


def _own_rows(spec: ParamSpec, groups) -> np.ndarray | None:
    """``(N,)`` bool rows a frame parameter acts on (None: every row)."""
    if spec.group == "base":
        return groups.station == 0
    if spec.group == "station":
        return groups.station == spec.joint
    if spec.group == "tool":
        return groups.tool == 0
    if spec.group == "tools":
        return groups.tool == spec.joint
    return None


def linearize(state, specs, scale, q_eff_all, xyz, R_meas, w, chunk=CHUNK, keep_rows=None, payload=None, groups=None):
    """Accumulate scaled normal equations over chunks (``q_eff_all``: deflected joints of ``state``;
    ``groups``: the rows' stations and tools or None).

    Returns dict with JtJ_p, JtJ_o (P,P), Jtr (P,), sse_p, sse_o, and (if keep_rows) the scaled
    Jacobian rows ``J_id`` ``(rows, P)`` of the samples ``keep_rows`` (``J_id_rot``: which are orientation rows).
    """
    P = len(specs)
    with_rot = R_meas is not None
    out = {"JtJ_p": np.zeros((P, P)), "JtJ_o": np.zeros((P, P)), "Jtr": np.zeros(P), "sse_p": 0.0, "sse_o": 0.0}
    need_tau = any(s.group == "comp" for s in specs)
    kept, kept_rot = [], []
    sc = scale[:, None, None]
    for lo in range(0, q_eff_all.shape[0], chunk):
        sl = slice(lo, lo + chunk)
        q_eff = np.ascontiguousarray(q_eff_all[sl])
        tau = gravity_torques(state.robot, q_eff, **payload_kwargs(payload, sl)) if need_tau else None
        Jp, Jo, tcp = jacobian_chunk(state, specs, q_eff, tau, w, with_rot, None if groups is None else groups.subset(sl))
        rp, ro = residual(tcp, xyz[sl], None if R_meas is None else R_meas[sl], w, state.pts)
        Jp *= sc[..., None]
        Jp2 = Jp.reshape(P, -1)
        out["JtJ_p"] += gram(Jp2.T)
        out["Jtr"] += Jp2 @ rp.reshape(-1)
        out["sse_p"] += float(np.sum(rp * rp))
        if with_rot:
            Jo *= sc
            Jo2 = Jo.reshape(P, -1)
            out["JtJ_o"] += gram(Jo2.T)
            out["Jtr"] += Jo2 @ ro.reshape(-1)
            out["sse_o"] += float(np.sum(ro * ro))
        if keep_rows is not None:
            idx = keep_rows[(keep_rows >= lo) & (keep_rows < lo + q_eff.shape[0])] - lo
            if idx.size:
                rows = [Jp[:, idx].reshape(P, -1).T]
                if with_rot:
                    rows.append(Jo[:, idx].reshape(P, -1).T)
                kept.append(np.concatenate(rows, 0))
                kept_rot.append(np.arange(kept[-1].shape[0]) >= rows[0].shape[0])
    if keep_rows is not None:
        out["J_id"] = np.concatenate(kept, 0) if kept else np.zeros((0, P))
        out["J_id_rot"] = np.concatenate(kept_rot) if kept else np.zeros(0, bool)  # orientation rows
    return out


def identification_jacobian(robot: Robot, q, *, position_only: bool = False, orientation_weight_m_per_rad: float = 1.0,
                            base: bool = True, tool: bool = True, compliance: bool = True, payload_kg=None,
                            payload_com_m=None):
    """Analytic identification Jacobian at ``robot`` for joints ``q`` ``(N, n)``.

    Returns ``(names, J)`` with ``J`` ``(N, 3 or 6, P)``: derivative of the modelled TCP position (m)
    and, unless ``position_only``, of ``w ·`` its rotation vector (world frame) with respect to each
    parameter deviation (SI units). Compliance columns are evaluated at the robot's own compliance,
    under the per-row payload ``payload_kg`` / ``payload_com_m`` when given (else the robot's).
    """
    specs = candidate_specs(robot, base=base, tool=tool, compliance=compliance)
    q = np.ascontiguousarray(np.asarray(q, dtype=np.float64).reshape(-1, robot.dof))
    state = ModelState(robot=robot, c=compliance_of(robot))
    from ..io.payload import payload_of

    pl = payload_of((), payload_kg, payload_com_m, n_rows=q.shape[0]) if payload_kg is not None else None
    q_eff = effective_joints(state, q, pl)
    tau = gravity_torques(robot, np.ascontiguousarray(q_eff), **payload_kwargs(pl)) if compliance else None
    w = orientation_weight_m_per_rad
    Jp, Jo, _ = jacobian_chunk(state, specs, np.ascontiguousarray(q_eff), tau, w, not position_only)
    Jp = Jp[:, :, 0]
    J = -Jp if position_only else -np.concatenate([Jp, Jo], 2)
    return [s.name for s in specs], np.ascontiguousarray(J.transpose(1, 2, 0))
