"""Forward kinematics and geometric Jacobians, batched over ``(N, dof)`` joint arrays, float64.

* :func:`fk` — TCP poses in the world frame ``(N, 4, 4)``; a compiled (numba) kernel when numba is
  installed, a vectorised numpy fallback otherwise. Both agree to ~1e-15 (the numba kernels use a
  vectorised Cephes sin/cos, within one ulp of libm's); single-pose and batched numba results are
  bit-identical.
* :func:`fk_frames` — joint frames, link frames and TCP of every sample.
* :func:`jacobian` — geometric Jacobian of the TCP ``(N, 6, dof)``, rows ``[v; ω]`` in the world frame.
* :func:`fk_torch` — differentiable twin in PyTorch (float64), same numbers to rounding.

Joints are in rad (revolute) or m (prismatic); positions in m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chain import Chain, _elem, chain_of
from .robot import Robot

__all__ = ["HAVE_NUMBA", "FKFrames", "fk", "fk_chain", "fk_frames", "fk_torch", "jacobian"]

try:  # numba is optional: it makes single-pose FK ~50x and batched FK ~5x faster than numpy.
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised in environments without numba
    numba = None
    HAVE_NUMBA = False


def _as_joints(robot_dof: int, q) -> tuple[np.ndarray, bool]:
    q = np.asarray(q, dtype=np.float64)
    single = q.ndim == 1
    q2 = np.ascontiguousarray(q.reshape(1, -1) if single else q)
    if q2.ndim != 2 or q2.shape[1] != robot_dof:
        raise ValueError(f"joints must have shape (N, {robot_dof}) or ({robot_dof},), got {q.shape}")
    return q2, single


# --------------------------------------------------------------------------- numpy reference


def _fk_numpy(fixed: np.ndarray, prismatic: np.ndarray, q: np.ndarray) -> np.ndarray:
    N, n = q.shape
    T = np.broadcast_to(fixed[0], (N, 4, 4)).copy()
    for i in range(n):
        if prismatic[i]:
            T[:, :3, 3] += T[:, :3, 2] * q[:, i : i + 1]
        else:
            c, s = np.cos(q[:, i])[:, None], np.sin(q[:, i])[:, None]
            x, y = T[:, :3, 0].copy(), T[:, :3, 1]
            T[:, :3, 0] = c * x + s * y
            T[:, :3, 1] = c * y - s * x
        T = T @ fixed[i + 1]
    return T


# --------------------------------------------------------------------------- numba kernels

# Cephes sin/cos (Moshier): reduction by pi/4 in three parts, minimax polynomials; |error| <= 2.3e-16
# for the joint ranges of robots (|q| < 1e6 rad). Unlike libm calls, these loops vectorise (AVX2: ~4 ns
# per sin/cos pair instead of ~35 ns), which makes trigonometry a small part of FK. Results differ
# from libm's by at most one unit in the last place.
_DP1 = 7.85398125648498535156e-1
_DP2 = 3.77489470793079817668e-8
_DP3 = 2.69515142907905952645e-15
_FOUR_OVER_PI = 1.27323954473516268615
_BLOCK = 256  # poses per block in the batched kernels (sin/cos buffer stays in L1)

if HAVE_NUMBA:

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def _sincos(x):  # pragma: no cover - compiled
        """``(sin x, cos x)``, branch-free so that loops over it vectorise."""
        ax = abs(x)
        y = np.floor(ax * _FOUR_OVER_PI)
        y = y + (y - 2.0 * np.floor(y * 0.5))  # next even integer
        j = y - 8.0 * np.floor(y * 0.125)  # octant 0, 2, 4 or 6
        z = ((ax - y * _DP1) - y * _DP2) - y * _DP3
        zz = z * z
        ps = z + z * zz * (
            ((((1.58962301576546568060e-10 * zz - 2.50507477628578072866e-8) * zz + 2.75573136213857245213e-6) * zz
              - 1.98412698295895385996e-4) * zz + 8.33333333332211858878e-3) * zz - 1.66666666666666307295e-1
        )
        pc = 1.0 - 0.5 * zz + zz * zz * (
            ((((-1.13585365213876817300e-11 * zz + 2.08757008419747316778e-9) * zz - 2.75573141792967388112e-7) * zz
              + 2.48015872888517045348e-5) * zz - 1.38888888888730564116e-3) * zz + 4.16666666666665929218e-2
        )
        swap = (j == 2.0) | (j == 6.0)
        sn = pc if swap else ps
        cs = ps if swap else pc
        sn = -sn if j >= 4.0 else sn
        cs = -cs if (j == 2.0) | (j == 4.0) else cs
        sn = -sn if x < 0.0 else sn
        return sn, cs

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def _first(F):  # pragma: no cover - compiled
        return (F[0, 0], F[0, 1], F[0, 2], F[0, 3], F[1, 0], F[1, 1], F[1, 2], F[1, 3],
                F[2, 0], F[2, 1], F[2, 2], F[2, 3])

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def _step(st, F, prism, qi, sq, cq):  # pragma: no cover - compiled
        """Running top 3x4 ``st`` (12 scalars) times J(q_i) times fixed transform ``F``."""
        a0, a1, a2, a3, b0, b1, b2, b3, c0, c1, c2, c3 = st
        if prism:
            a3 += a2 * qi
            b3 += b2 * qi
            c3 += c2 * qi
        else:
            x, y = a0, a1
            a0 = cq * x + sq * y
            a1 = cq * y - sq * x
            x, y = b0, b1
            b0 = cq * x + sq * y
            b1 = cq * y - sq * x
            x, y = c0, c1
            c0 = cq * x + sq * y
            c1 = cq * y - sq * x
        f00, f01, f02, f03 = F[0, 0], F[0, 1], F[0, 2], F[0, 3]
        f10, f11, f12, f13 = F[1, 0], F[1, 1], F[1, 2], F[1, 3]
        f20, f21, f22, f23 = F[2, 0], F[2, 1], F[2, 2], F[2, 3]
        return (
            a0 * f00 + a1 * f10 + a2 * f20, a0 * f01 + a1 * f11 + a2 * f21,
            a0 * f02 + a1 * f12 + a2 * f22, a0 * f03 + a1 * f13 + a2 * f23 + a3,
            b0 * f00 + b1 * f10 + b2 * f20, b0 * f01 + b1 * f11 + b2 * f21,
            b0 * f02 + b1 * f12 + b2 * f22, b0 * f03 + b1 * f13 + b2 * f23 + b3,
            c0 * f00 + c1 * f10 + c2 * f20, c0 * f01 + c1 * f11 + c2 * f21,
            c0 * f02 + c1 * f12 + c2 * f22, c0 * f03 + c1 * f13 + c2 * f23 + c3,
        )

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def _store(st, out):  # pragma: no cover - compiled
        out[0, 0], out[0, 1], out[0, 2], out[0, 3] = st[0], st[1], st[2], st[3]
        out[1, 0], out[1, 1], out[1, 2], out[1, 3] = st[4], st[5], st[6], st[7]
        out[2, 0], out[2, 1], out[2, 2], out[2, 3] = st[8], st[9], st[10], st[11]
        out[3, 0] = 0.0
        out[3, 1] = 0.0
        out[3, 2] = 0.0
        out[3, 3] = 1.0

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def _fk_one(fixed, prismatic, q, out):  # pragma: no cover - compiled
        """FK of one pose ``q`` (n,) into ``out`` (4, 4); same numbers as the batched kernels."""
        st = _first(fixed[0])
        for i in range(q.shape[0]):
            sq, cq = _sincos(q[i])
            st = _step(st, fixed[i + 1], prismatic[i], q[i], sq, cq)
        _store(st, out)

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def _fk_block(fixed, prismatic, q, k0, k1, sbuf, cbuf, out):  # pragma: no cover - compiled
        """Poses ``k0:k1``: vectorised sin/cos of the whole block first, then the chain per pose."""
        n = q.shape[1]
        qf = q.reshape(q.shape[0] * n)  # C-contiguous: a view
        j0 = k0 * n
        for j in range((k1 - k0) * n):  # one flat, vectorisable loop
            sbuf[j], cbuf[j] = _sincos(qf[j0 + j])
        for t in range(k1 - k0):
            st = _first(fixed[0])
            for i in range(n):
                st = _step(st, fixed[i + 1], prismatic[i], qf[j0 + t * n + i], sbuf[t * n + i], cbuf[t * n + i])
            _store(st, out[k0 + t])

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def _fk_batch_serial(fixed, prismatic, q, out):  # pragma: no cover - compiled
        N, n = q.shape
        sbuf = np.empty(_BLOCK * n)
        cbuf = np.empty(_BLOCK * n)
        for k0 in range(0, N, _BLOCK):
            _fk_block(fixed, prismatic, q, k0, min(k0 + _BLOCK, N), sbuf, cbuf, out)

    @numba.njit(cache=True, fastmath=False, nogil=True, parallel=True)
    def _fk_batch_parallel(fixed, prismatic, q, out):  # pragma: no cover - compiled
        N, n = q.shape
        nb = (N + _BLOCK - 1) // _BLOCK
        for b in numba.prange(nb):
            sbuf = np.empty(_BLOCK * n)
            cbuf = np.empty(_BLOCK * n)
            k0 = b * _BLOCK
            _fk_block(fixed, prismatic, q, k0, min(k0 + _BLOCK, N), sbuf, cbuf, out)


_PARALLEL_MIN = 20_000  # below this, thread start-up costs more than it saves


def fk_chain(chain: Chain, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """FK of a numpy :class:`Chain` for ``q`` ``(N, dof)`` (contiguous float64) -> ``(N, 4, 4)``."""
    fixed = np.ascontiguousarray(chain.fixed, dtype=np.float64)
    prism = np.ascontiguousarray(chain.prismatic, dtype=np.bool_)
    q = np.ascontiguousarray(q, dtype=np.float64)
    if not HAVE_NUMBA:
        return _fk_numpy(fixed, prism, q)
    if out is None:
        out = np.empty((q.shape[0], 4, 4))
    if q.shape[0] >= _PARALLEL_MIN:
        _fk_batch_parallel(fixed, prism, q, out)
    else:
        _fk_batch_serial(fixed, prism, q, out)
    return out


def fk(robot: Robot, q) -> np.ndarray:
    """TCP pose(s) in the world frame: ``base · chain(q) · tool``.

    ``q``: ``(N, dof)`` or ``(dof,)`` joints (rad / m). Returns ``(N, 4, 4)`` or ``(4, 4)`` float64.
    A single float64 pose takes a fast path (no reshaping or copies) with the same numbers.
    """
    ch = chain_of(robot)
    if HAVE_NUMBA and type(q) is np.ndarray and q.ndim == 1 and q.dtype == _F64:
        fixed = ch.fixed
        if q.shape[0] + 1 == fixed.shape[0]:
            out = np.empty((4, 4))
            if q.strides[0] == 8 and _ONE_ENTRY:
                _ONE_ENTRY[0](fixed, ch.prismatic, q, out)
            else:
                _fk_one(fixed, ch.prismatic, q, out)
                if not _ONE_ENTRY and q.strides[0] == 8:
                    _ONE_ENTRY.extend(_native_entry(fixed, ch.prismatic, q, out))
            return out
    q2, single = _as_joints(robot.dof, q)
    T = fk_chain(ch, q2)
    return T[0] if single else T


_F64 = np.dtype(np.float64)
# Native entry point of ``_fk_one`` for (C float64 3-D, C bool 1-D, C float64 1-D, C float64 2-D)
# arguments: calling it skips numba's per-call type dispatch (~0.5 µs). ``fk`` only uses it for
# arguments of exactly those types (chain arrays from ``build_chain``, contiguous float64 ``q``).
_ONE_ENTRY: list = []


def _native_entry(fixed, prismatic, q, out) -> list:
    try:
        sig = tuple(numba.typeof(a) for a in (fixed, prismatic, q, out))
        if any(getattr(t, "readonly", False) or t.layout != "C" for t in sig):
            return []
        return [_fk_one.overloads[sig].entry_point]
    except Exception:  # noqa: BLE001 - numba internals changed: keep the dispatcher
        return []


# --------------------------------------------------------------------------- all frames


@dataclass
class FKFrames:
    """All frames of a batch, world coordinates, float64.

    joint: ``(N, n, 4, 4)`` joint frames (z = joint axis, origin on the axis).
    link: ``(N, n, 4, 4)`` link frames (DH/MDH frame i, URDF child link i); ``link[:, -1]`` is the flange.
    tcp: ``(N, 4, 4)`` TCP = flange · tool.
    """

    joint: np.ndarray
    link: np.ndarray
    tcp: np.ndarray


def _frames_xp(xp, chain: Chain, q):
    N, n = q.shape
    T = chain.base
    joints, links = [], []
    for i in range(n):
        A = T @ chain.pre[i]
        if chain.prismatic[i]:
            Jt = _elem(xp, "tz", q[:, i])
        else:
            Jt = _elem(xp, "rz", q[:, i])
        Jf = A @ Jt
        joints.append(Jf)
        T = Jf @ chain.post[i]
        links.append(T)
    tcp = T @ chain.tool
    return xp.stack(joints, 1), xp.stack(links, 1), tcp


def fk_frames(robot: Robot, q) -> FKFrames:
    """Joint frames, link frames and TCP for ``q`` ``(N, dof)`` (see :class:`FKFrames`)."""
    q2, _ = _as_joints(robot.dof, q)
    j, l, t = _frames_xp(np, chain_of(robot), q2)
    return FKFrames(joint=j, link=l, tcp=t)


def jacobian(robot: Robot, q, frames: FKFrames | None = None) -> np.ndarray:
    """Geometric Jacobian of the TCP, ``(N, 6, dof)``, rows ``[v (m per unit); ω (rad per unit)]``.

    World-frame velocities of the TCP point: column i is ``[z_i × (p − o_i); z_i]`` for a revolute
    joint and ``[z_i; 0]`` for a prismatic one.
    """
    q2, single = _as_joints(robot.dof, q)
    fr = fk_frames(robot, q2) if frames is None else frames
    z = fr.joint[..., :3, 2]  # (N, n, 3)
    o = fr.joint[..., :3, 3]
    p = fr.tcp[:, None, :3, 3]
    prism = np.asarray([t == "prismatic" for t in robot.joint_type])
    Jv = np.where(prism[None, :, None], z, np.cross(z, p - o))
    Jw = np.where(prism[None, :, None], 0.0, z)
    J = np.concatenate([Jv, Jw], axis=-1).transpose(0, 2, 1)
    return J[0] if single else J


# --------------------------------------------------------------------------- torch


def fk_torch(robot: Robot, q, chain: Chain | None = None, frames: bool = False):
    """Differentiable FK in PyTorch. ``q``: tensor ``(N, dof)``; returns ``(N, 4, 4)``.

    ``chain``: a chain built with ``build_chain(robot, geom, xp=torch)`` to differentiate with
    respect to geometry; by default the robot's nominal chain (as float64 tensors, on q's device).
    With ``frames=True`` returns ``(joint_frames, link_frames, tcp)`` as in :class:`FKFrames`.
    """
    import torch

    if chain is None:
        ch = chain_of(robot)
        conv = lambda x: torch.as_tensor(x, dtype=q.dtype, device=q.device)
        chain = Chain(
            pre=conv(ch.pre), post=conv(ch.post), fixed=conv(ch.fixed), base=conv(ch.base),
            tool=conv(ch.tool), prismatic=ch.prismatic,
        )
    if frames:
        return _frames_xp(torch, chain, q)
    T = chain.fixed[0].expand(q.shape[0], 4, 4)
    for i in range(chain.dof):
        J = _elem(torch, "tz" if chain.prismatic[i] else "rz", q[:, i])
        T = T @ J @ chain.fixed[i + 1]
    return T
