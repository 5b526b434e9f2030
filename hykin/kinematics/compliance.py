"""Joint compliance under gravity: gravity torques, static deflection, compliant FK (numpy and torch).

Physics (DESIGN.md §1.4). Each joint is a torsional (or linear, for prismatic joints) spring of
stiffness ``k_i`` between the motor side (commanded ``q_i``) and the link side. At static
equilibrium the spring balances the generalized gravity force of everything beyond it:

    k_i (q_eff,i - q_i) = tau_i(q_eff)    <=>    q_eff = q + C tau(q_eff),   C = diag(1 / k),

with ``tau = -dV/dq`` the generalized gravity force, ``V = -sum_j m_j g . c_j`` the potential energy
of link masses ``m_j`` at their centres of mass ``c_j`` (``Robot.com_m``, in link frame j) and of the
payload (``Robot.payload_kg``, a point mass at the TCP). With joint axis ``z_i`` through ``o_i``
(world frame) and world gravity ``g = base_R @ gravity_base``:

* revolute:  ``tau_i = sum_{j >= i} (z_i x (c_j - o_i)) . (m_j g)``  (N·m)
* prismatic: ``tau_i = z_i . sum_{j >= i} m_j g``                      (N)

Torques do not depend on the world frame (rotating frames and gravity together changes nothing),
so a calibrated base frame does not change them. The fixed point is found by iteration
(contraction factor ~ ``C dtau/dq`` ~ 1e-3 for real arms) to 1e-13 rad; the torch path keeps the
iterations in the autograd graph, so gradients with respect to geometry and compliance are those of
the converged equilibrium.

Everything is vectorised over ``(N, n)`` joint arrays and float64; numpy and torch give the same
numbers to rounding. The numpy path runs compiled (numba) per-sample kernels, ~0.5 M torque
evaluations/s per core; the array-namespace code (:func:`_gravity_torques_xp`) serves torch and
is the numpy fallback without numba.

Mimic joints (URDF ``<mimic>``): each chain joint is a spring of its own, so torques, compliance,
stiffness and deflected joints are per chain joint (``n = robot.n_chain``); the joints given may be
the independent ones (expanded by :func:`hykin.kinematics.walk.expand_joints`) or chain joints.
"""

from __future__ import annotations

import sys

import numpy as np

from .chain import Chain, chain_of
from .chunks import run_chunked
from .fk import HAVE_NUMBA, fk, fk_torch
from .robot import Robot
from .walk import chain_walk, expand_joints

if HAVE_NUMBA:
    import numba

    from .walk import joint_motion_top, sincos, times_fixed, top_rows

__all__ = [
    "compliance_of",
    "compliant_fk",
    "compliant_fk_torch",
    "deflected_joints",
    "gravity_torques",
    "payload_rows",
    "potential_energy",
]

TOL_RAD = 1e-13
MAX_ITER = 12
# Acceptance after MAX_ITER steps (the 1e-13 target can sit below the rounding floor of large
# torques or of a prismatic column's metres): the last update is at most CONVERGED_ATOL (rad, or m
# for a prismatic joint: 1 nrad moves a 3 m arm's TCP by 3 nm) plus CONVERGED_RTOL times the
# deflection itself. A joint too soft for an equilibrium diverges by orders of magnitude more.
CONVERGED_ATOL = 1e-9
CONVERGED_RTOL = 1e-6


class ComplianceError(ValueError):
    """Bad input to the compliance functions (shapes, non-finite or negative values)."""


def _is_torch(x) -> bool:
    torch = sys.modules.get("torch")  # never import torch just to ask (slow start-up)
    return torch is not None and isinstance(x, torch.Tensor)


# --------------------------------------------------------------------------- numba kernels (numpy path)

if HAVE_NUMBA:

    @numba.njit(cache=True, nogil=True)
    def _tau_ws(fixed, post, ppt, prism, com, mass, payload, g, q, out, z, o, cm):  # pragma: no cover
        """Gravity torques of one sample into ``out``; ``payload`` (kg) at ``ppt`` (3,) (flange frame);
        ``z``, ``o``, ``cm`` (n, 3) scratch. Walks the chain with the shared step (:mod:`.walk`)."""
        n = q.shape[0]
        st = top_rows(fixed[0])
        T = st
        for i in range(n):
            sq, cq = sincos(q[i])
            J = joint_motion_top(st, prism[i], q[i], sq, cq)  # joint frame i
            z[i, 0], z[i, 1], z[i, 2] = J[2], J[6], J[10]
            o[i, 0], o[i, 1], o[i, 2] = J[3], J[7], J[11]
            T = times_fixed(J, post[i])  # link frame i
            for r in range(3):
                cm[i, r] = T[4 * r] * com[i, 0] + T[4 * r + 1] * com[i, 1] + T[4 * r + 2] * com[i, 2] + T[4 * r + 3]
            st = times_fixed(J, fixed[i + 1])
        # payload at its point (the TCP by default: ppt = tool[:3, 3])
        Fs0, Fs1, Fs2 = payload * g[0], payload * g[1], payload * g[2]
        p0 = T[0] * ppt[0] + T[1] * ppt[1] + T[2] * ppt[2] + T[3]
        p1 = T[4] * ppt[0] + T[5] * ppt[1] + T[6] * ppt[2] + T[7]
        p2 = T[8] * ppt[0] + T[9] * ppt[1] + T[10] * ppt[2] + T[11]
        Ms0 = p1 * Fs2 - p2 * Fs1
        Ms1 = p2 * Fs0 - p0 * Fs2
        Ms2 = p0 * Fs1 - p1 * Fs0
        for i in range(n - 1, -1, -1):
            f0, f1, f2 = mass[i] * g[0], mass[i] * g[1], mass[i] * g[2]
            c0, c1, c2 = cm[i, 0], cm[i, 1], cm[i, 2]
            Ms0 += c1 * f2 - c2 * f1
            Ms1 += c2 * f0 - c0 * f2
            Ms2 += c0 * f1 - c1 * f0
            Fs0 += f0
            Fs1 += f1
            Fs2 += f2
            if prism[i]:
                out[i] = z[i, 0] * Fs0 + z[i, 1] * Fs1 + z[i, 2] * Fs2
            else:
                o0, o1, o2 = o[i, 0], o[i, 1], o[i, 2]
                m0 = Ms0 - (o1 * Fs2 - o2 * Fs1)
                m1 = Ms1 - (o2 * Fs0 - o0 * Fs2)
                m2 = Ms2 - (o0 * Fs1 - o1 * Fs0)
                out[i] = z[i, 0] * m0 + z[i, 1] * m1 + z[i, 2] * m2

    # Per-row payload: ``payload`` (N,) kg and ``ppt`` (N, 3) its point in the flange frame (the
    # robot's scalar payload at the TCP is the broadcast of one value: same operations, same numbers).

    @numba.njit(cache=True, nogil=True)
    def _tau_range(fixed, post, ppt, prism, com, mass, payload, g, q, out, k0, k1):  # pragma: no cover
        """Gravity torques of rows ``k0:k1`` (:func:`_tau_ws`), sharing one set of scratch arrays."""
        n = q.shape[1]
        z, o, cm = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        for k in range(k0, k1):
            _tau_ws(fixed, post, ppt[k], prism, com, mass, payload[k], g, q[k], out[k], z, o, cm)

    @numba.njit(cache=True, nogil=True)
    def _deflect_one(fixed, post, ppt, prism, com, mass, payload, g, C, q, min_it, max_it, tol, out,
                     tau, z, o, cm):  # pragma: no cover
        """Fixed point q_eff = q + C tau(q_eff) of one sample into ``out``; returns the last update.
        ``tau`` (n,), ``z``, ``o``, ``cm`` (n, 3): scratch (no allocation per sample)."""
        n = q.shape[0]
        for i in range(n):
            out[i] = q[i]
        step = np.inf
        for it in range(max_it):
            _tau_ws(fixed, post, ppt, prism, com, mass, payload, g, out, tau, z, o, cm)
            step = 0.0
            for i in range(n):
                new = q[i] + C[i] * tau[i]
                d = abs(new - out[i])
                step = max(step, d)
                out[i] = new
            if it + 1 >= min_it and step < tol:
                break
        return step

    @numba.njit(cache=True, nogil=True)
    def _deflect_range(fixed, post, ppt, prism, com, mass, payload, g, C, q, min_it, max_it, tol, out, steps,
                       lo, hi):  # pragma: no cover
        """Samples ``lo:hi`` of :func:`_deflect_one`, sharing one set of scratch arrays."""
        n = q.shape[1]
        tau = np.empty(n)
        z = np.empty((n, 3))
        o = np.empty((n, 3))
        cm = np.empty((n, 3))
        for k in range(lo, hi):
            steps[k] = _deflect_one(fixed, post, ppt[k], prism, com, mass, payload[k], g, C, q[k], min_it, max_it,
                                    tol, out[k], tau, z, o, cm)

    #: public name of the one-sample deflection kernel (the fast hybrid kernel of hykin.hybrid calls it)
    deflect_one = _deflect_one

_PARALLEL_MIN = 512  # rows (~1 ms of deflection) below which waking a worker thread costs more than it saves


def _kernel_args(robot: Robot, chain: Chain | None, N: int, payload=None):
    """Arguments of the numba kernels; ``payload``: ``(kg (N,), com (N, 3) tool frame | None)`` or
    None (the robot's scalar payload at the TCP)."""
    ch = chain_of(robot) if chain is None else chain
    c = lambda x: np.ascontiguousarray(x, dtype=np.float64)
    g = np.asarray(ch.base)[:3, :3] @ np.asarray(robot.gravity_base, dtype=np.float64)
    tool = np.asarray(ch.tool, dtype=np.float64)
    if payload is None:
        kg = np.full(N, float(robot.payload_kg))
        ppt = np.broadcast_to(tool[:3, 3], (N, 3))
    else:
        kg, com = payload
        ppt = np.broadcast_to(tool[:3, 3], (N, 3)) if com is None else com @ tool[:3, :3].T + tool[:3, 3]
    return (
        c(ch.fixed), c(ch.post), c(ppt), np.ascontiguousarray(ch.prismatic, dtype=np.bool_),
        c(robot.com_m), c(robot.mass_kg), c(kg), c(g),
    )


def payload_rows(N: int, payload_kg=None, payload_com_m=None, like=None):
    """Validated per-row payload ``(kg (N,), com (N, 3) m in the tool frame or None)``, or None when
    both are None (the robot's own payload). ``payload_kg``: scalar or ``(N,)`` kg >= 0;
    ``payload_com_m``: ``(3,)`` or ``(N, 3)`` (default: the TCP). numpy, or torch tensors like ``like``."""
    if payload_kg is None and payload_com_m is None:
        return None
    if payload_kg is None:
        raise ComplianceError("payload_com_m given without payload_kg")
    if _is_torch(like):
        import torch

        kg = torch.as_tensor(payload_kg, dtype=like.dtype, device=like.device).reshape(-1)
        kg = kg.expand(N) if kg.numel() == 1 else kg
        if kg.shape != (N,) or not bool(torch.isfinite(kg).all()) or bool((kg < 0).any()):
            raise ComplianceError(f"payload_kg must be a finite value >= 0 or ({N},) such values")
        com = None
        if payload_com_m is not None:
            com = torch.as_tensor(payload_com_m, dtype=like.dtype, device=like.device)
            com = com.reshape(1, 3).expand(N, 3) if com.numel() == 3 else com
            if com.shape != (N, 3) or not bool(torch.isfinite(com).all()):
                raise ComplianceError(f"payload_com_m must be finite, (3,) or ({N}, 3)")
        return kg, com
    given = np.asarray(payload_kg, dtype=np.float64)
    kg = given.reshape(-1)
    scalar = kg.size == 1
    kg = np.full(N, float(kg[0])) if scalar else kg
    if kg.shape != (N,):
        raise ComplianceError(f"payload_kg must be a scalar or ({N},), got shape {given.shape}")
    bad = ~(np.isfinite(kg) & (kg >= 0))
    if bad.any():
        where = "" if scalar else f" row {int(np.argmax(bad)) + 1}:"
        raise ComplianceError(f"payload_kg:{where} {kg[bad][0]} is not a finite mass >= 0 kg")
    com = None
    if payload_com_m is not None:
        com = np.asarray(payload_com_m, dtype=np.float64)
        com = np.broadcast_to(com.reshape(1, 3), (N, 3)) if com.size == 3 else com
        if com.shape != (N, 3):
            raise ComplianceError(f"payload_com_m must be (3,) or ({N}, 3), got shape {com.shape}")
        bad = ~np.isfinite(com).all(1)
        if bad.any():
            raise ComplianceError(f"payload_com_m: row {int(np.argmax(bad)) + 1}: non-finite centre of mass")
    return kg, com


def _frames(robot: Robot, q, chain: Chain | None, xp):
    """(joint frames (N,n,4,4), link frames (N,n,4,4), tcp (N,4,4), base (4,4)) in namespace xp."""
    if xp is np:
        ch = chain_of(robot) if chain is None else chain
        j, l, t = chain_walk(np, ch, q, frames=True)
        return j, l, t, np.asarray(ch.base)
    j, l, t = fk_torch(robot, q, chain=chain, frames=True)
    base = chain.base if chain is not None else xp.as_tensor(np.array(robot.base), dtype=q.dtype, device=q.device)
    return j, l, t, base


def _check_q(robot: Robot, q, xp):
    if xp is np:
        q = np.asarray(q, dtype=np.float64)
    elif not _is_torch(q):
        q = xp.as_tensor(np.array(q, dtype=np.float64))
    if q.ndim != 2 or q.shape[1] not in (robot.dof, robot.n_chain):
        raise ComplianceError(f"joints must have shape (N, {robot.dof}), got {tuple(q.shape)}")
    return expand_joints(xp, chain_of(robot), q)  # chain joints (mimic joints expanded)


def _mass_terms(robot: Robot, links, tcp, base, xp, like, payload=None):
    """World COM positions (N, n+1, 3), masses (n+1,) — ``(N, n+1)`` with a per-row ``payload``
    (:func:`payload_rows`) —, world gravity (3,) (last entry = payload)."""
    conv = (lambda x: np.asarray(x, dtype=np.float64)) if xp is np else (
        lambda x: xp.as_tensor(np.array(x, dtype=np.float64), dtype=like.dtype, device=like.device)
    )
    com = conv(robot.com_m)  # (n, 3)
    c_links = links[..., :3, :3] @ com[None, :, :, None]
    c_links = c_links[..., 0] + links[..., :3, 3]  # (N, n, 3)
    cat = np.concatenate if xp is np else xp.cat
    if payload is None:
        c = cat([c_links, tcp[:, None, :3, 3]], 1)
        m = conv(np.append(robot.mass_kg, robot.payload_kg))
    else:
        kg, com = payload
        p = tcp[:, :3, 3] if com is None else (tcp[:, :3, :3] @ com[:, :, None])[..., 0] + tcp[:, :3, 3]
        c = cat([c_links, p[:, None]], 1)
        ml, N = conv(robot.mass_kg), kg.shape[0]
        m = cat([np.broadcast_to(ml, (N, ml.shape[0])) if xp is np else ml.expand(N, -1), kg[:, None]], 1)
    g = base[:3, :3] @ conv(robot.gravity_base)
    return c, m, g


def gravity_torques(robot: Robot, q, chain: Chain | None = None, xp=np, payload_kg=None, payload_com_m=None):
    """Generalized gravity force on each joint ``tau = -dV/dq``, ``(N, n)`` (N·m; N for prismatic).

    ``q``: ``(N, n)`` joints (numpy array, or a float64 torch tensor with ``xp=torch``). ``chain``:
    a :class:`~hykin.kinematics.chain.Chain` (numpy, or torch from ``build_chain(robot, geom, torch)`` to
    differentiate with respect to geometry); default: the robot's own chain. Masses, centres of
    mass, payload and gravity come from ``robot``. ``payload_kg`` (scalar or ``(N,)`` kg) and
    ``payload_com_m`` (``(3,)`` or ``(N, 3)`` m, tool frame; default the TCP) replace the robot's
    payload row by row (:mod:`hykin.io.payload`).
    """
    if _is_torch(q):
        import torch

        xp = torch
    q = _check_q(robot, q, xp)
    payload = payload_rows(q.shape[0], payload_kg, payload_com_m, like=q)
    if xp is np and HAVE_NUMBA:
        out = np.empty(q.shape)
        run_chunked(_tau_range, (*_kernel_args(robot, chain, q.shape[0], payload), np.ascontiguousarray(q), out),
                    q.shape[0], min_chunk=_PARALLEL_MIN // 2)
        return out
    return _gravity_torques_xp(robot, q, chain, xp, payload)


def _gravity_torques_xp(robot: Robot, q, chain: Chain | None, xp, payload=None):
    """Array-namespace implementation of :func:`gravity_torques` (torch path, numpy fallback)."""
    joints, links, tcp, base = _frames(robot, q, chain, xp)
    c, m, g = _mass_terms(robot, links, tcp, base, xp, q, payload)
    if payload is not None:  # per-row masses: forces (N, n+1, 3)
        F = m[..., None] * g
        if xp is np:
            M = np.cross(c, F)
            Fs = np.cumsum(F[:, ::-1], 1)[:, ::-1]
            Ms = np.cumsum(M[:, ::-1], 1)[:, ::-1]
        else:
            M = xp.cross(c, F, dim=-1)
            Fs = xp.flip(xp.cumsum(xp.flip(F, [1]), 1), [1])
            Ms = xp.flip(xp.cumsum(xp.flip(M, [1]), 1), [1])
        Fs_n = Fs[:, : robot.n_chain]
    else:
        F = m[:, None] * g[None, :]  # (n+1, 3) forces
        if xp is np:
            M = np.cross(c, F[None])  # (N, n+1, 3) moments about the world origin
            Fs = np.cumsum(F[::-1], 0)[::-1]  # sum_{j>=i} F_j, (n+1, 3)
            Ms = np.cumsum(M[:, ::-1], 1)[:, ::-1]
        else:
            M = xp.cross(c, F[None].expand_as(c), dim=-1)
            Fs = xp.flip(xp.cumsum(xp.flip(F, [0]), 0), [0])
            Ms = xp.flip(xp.cumsum(xp.flip(M, [1]), 1), [1])
        Fs_n = Fs[None, : robot.n_chain]  # (1, n, 3)
    n = robot.n_chain
    z = joints[..., :3, 2]  # (N, n, 3)
    o = joints[..., :3, 3]
    # moment about o_i of the forces beyond joint i: sum (c_j - o_i) x F_j = Ms_i - o_i x Fs_i
    if xp is np:
        mom = Ms[:, :n] - np.cross(o, Fs_n)
        rev = np.einsum("nij,nij->ni", z, mom)
        pri = np.einsum("nij,nij->ni", z, np.broadcast_to(Fs_n, z.shape))
        prism = np.asarray(robot.joint_type) == "prismatic"
        return np.where(prism[None], pri, rev) if prism.any() else rev
    mom = Ms[:, :n] - xp.cross(o, Fs_n.expand_as(o), dim=-1)
    rev = (z * mom).sum(-1)
    prism = [t == "prismatic" for t in robot.joint_type]
    if any(prism):
        pri = (z * Fs_n).sum(-1)
        mask = xp.as_tensor(prism, device=q.device)
        return xp.where(mask[None], pri, rev)
    return rev


def potential_energy(robot: Robot, q, payload_kg=None, payload_com_m=None) -> np.ndarray:
    """Gravitational potential energy ``V = -sum_j m_j g . c_j`` (J), ``(N,)``; numpy.

    Independent reference for tests: ``gravity_torques == -dV/dq``.
    """
    q = _check_q(robot, q, np)
    fr = _frames(robot, q, None, np)
    payload = payload_rows(q.shape[0], payload_kg, payload_com_m)
    c, m, g = _mass_terms(robot, fr[1], fr[2], fr[3], np, q, payload)
    if payload is not None:
        return -np.einsum("nji,nj,i->n", c, m, g)
    return -np.einsum("nji,j,i->n", c, m, g)


def kernel_args(robot: Robot, N: int = 1) -> tuple:
    """Arguments ``(fixed, post, ppt (N, 3), prismatic, com, mass, payload_kg (N,), g)`` of the compiled
    gravity and deflection kernels for the robot's own payload."""
    return _kernel_args(robot, None, N)


def compliance_of(robot: Robot) -> np.ndarray:
    """``(n,)`` joint compliance ``1 / stiffness`` (rad/N·m; m/N prismatic); infinite stiffness -> 0."""
    k = np.asarray(robot.stiffness_nm_per_rad, dtype=np.float64)
    if np.any(~(k > 0)):
        raise ComplianceError(f"robot {robot.name!r}: stiffness must be > 0 (got {k})")
    return np.where(np.isinf(k), 0.0, 1.0 / k)


def deflected_joints(robot: Robot, q, compliance=None, chain: Chain | None = None, xp=np, iterations: int = 4,
                     payload_kg=None, payload_com_m=None):
    """Effective (link-side) joints at static equilibrium under gravity, ``(N, n)``.

    Solves ``q_eff = q + compliance * tau(q_eff)`` by fixed-point iteration: at least ``iterations``
    steps, then until the largest update is below 1e-13 rad (at most 12 steps; a robot so soft that
    it does not converge raises :class:`ComplianceError`). ``compliance``: ``(n,)`` rad/N·m (numpy or
    torch, differentiable), default ``compliance_of(robot)``. All-zero compliance returns ``q``.
    ``payload_kg`` / ``payload_com_m``: per-row payload as in :func:`gravity_torques`.
    """
    if _is_torch(q):
        import torch

        xp = torch
    q = _check_q(robot, q, xp)
    payload = payload_rows(q.shape[0], payload_kg, payload_com_m, like=q)
    if compliance is None:
        compliance = compliance_of(robot)
    if xp is np:
        C = np.asarray(compliance, dtype=np.float64)
        if C.shape != (robot.n_chain,) or not np.all(np.isfinite(C)) or np.any(C < 0):
            raise ComplianceError(f"compliance must be ({robot.n_chain},) finite and >= 0, got {C}")
        if not np.any(C):
            return q.copy()
    else:
        C = compliance if _is_torch(compliance) else xp.as_tensor(
            np.array(compliance, dtype=np.float64), dtype=q.dtype, device=q.device
        )
        if C.shape != (robot.n_chain,):
            raise ComplianceError(f"compliance must have shape ({robot.n_chain},), got {tuple(C.shape)}")
        if not C.requires_grad and not bool((C != 0).any()):
            return q.clone()
    if xp is np and HAVE_NUMBA:
        out, steps = np.empty(q.shape), np.empty(q.shape[0])
        args = (*_kernel_args(robot, chain, q.shape[0], payload), np.ascontiguousarray(C), np.ascontiguousarray(q),
                int(iterations), MAX_ITER, TOL_RAD, out, steps)
        run_chunked(_deflect_range, args, q.shape[0], min_chunk=_PARALLEL_MIN // 2)
        if steps.size:
            excess = steps - CONVERGED_RTOL * np.abs(out - q).max(axis=1)
            k = int(np.argmax(excess))
            _check_converged(robot, float(steps[k]), float(np.abs(out[k] - q[k]).max()))
        return out
    q_eff = q
    step = float("inf")
    for it in range(MAX_ITER):
        tau = gravity_torques(robot, q_eff, chain=chain, xp=xp) if payload is None else \
            _gravity_torques_xp(robot, q_eff, chain, xp, payload)
        new = q + C * tau
        diff = new - q_eff
        step = float(np.max(np.abs(diff))) if xp is np else float(diff.detach().abs().max())
        q_eff = new
        if it + 1 >= iterations and step < TOL_RAD:
            return q_eff
    defl = q_eff - q
    _check_converged(robot, step, float(np.max(np.abs(defl))) if xp is np else float(defl.detach().abs().max()))
    return q_eff


def _check_converged(robot: Robot, step: float, deflection: float = 0.0) -> None:
    """Raise unless the last fixed-point update ``step`` is negligible: at most
    :data:`CONVERGED_ATOL` + :data:`CONVERGED_RTOL` x ``deflection`` (the largest joint deflection of
    that sample, rad or m)."""
    if step <= CONVERGED_ATOL + CONVERGED_RTOL * deflection:
        return
    raise ComplianceError(
        f"robot {robot.name!r}: joint deflection did not converge (last update {step:.3g} rad or m for a "
        f"deflection of {deflection:.3g}); the joints are too soft for a static equilibrium near the commanded pose"
    )


def compliant_fk(robot: Robot, q, payload_kg=None, payload_com_m=None) -> np.ndarray:
    """TCP poses ``(N, 4, 4)`` of a compliant robot: ``fk(robot, deflected_joints(robot, q))``.

    Plain :func:`hykin.kinematics.fk.fk` when no joint has finite stiffness. ``q``: ``(N, n)`` or ``(n,)``.
    ``payload_kg`` / ``payload_com_m``: per-row payload as in :func:`gravity_torques`.
    """
    q = np.asarray(q, dtype=np.float64)
    if not robot.has_compliance:
        return fk(robot, q)
    single = q.ndim == 1
    q2 = q.reshape(1, -1) if single else q
    kw = {} if payload_kg is None and payload_com_m is None else {"payload_kg": payload_kg, "payload_com_m": payload_com_m}
    T = fk(robot, np.ascontiguousarray(deflected_joints(robot, q2, **kw)))
    return T[0] if single else T


def compliant_fk_torch(robot: Robot, q, chain: Chain | None = None, compliance=None, payload_kg=None,
                       payload_com_m=None):
    """Differentiable twin of :func:`compliant_fk`: ``q`` float64 tensor ``(N, n)`` -> ``(N, 4, 4)``.

    ``chain`` (torch, from ``build_chain(robot, geom, torch)``) and ``compliance`` (``(n,)`` tensor,
    rad/N·m) may carry gradients; defaults are the robot's own. ``payload_kg`` / ``payload_com_m``:
    per-row payload as in :func:`gravity_torques`.
    """
    q_eff = deflected_joints(robot, q, compliance=compliance, chain=chain, payload_kg=payload_kg,
                             payload_com_m=payload_com_m)
    return fk_torch(robot, q_eff, chain=chain)
