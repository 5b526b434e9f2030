"""Forward kinematics and geometric Jacobians, batched over ``(N, dof)`` joint arrays, float64.

* :func:`fk` — TCP poses in the world frame ``(N, 4, 4)``; a compiled (numba) kernel when numba is
  installed, a vectorised numpy fallback otherwise. Both agree to ~1e-15 (the numba kernels use a
  vectorised Cephes sin/cos, within one ulp of libm's); single-pose and batched numba results are
  bit-identical.
* :func:`fk_frames` — joint frames, link frames and TCP of every sample.
* :func:`jacobian` — geometric Jacobian of the TCP ``(N, 6, dof)``, rows ``[v; ω]`` in the world frame.
* :func:`fk_torch` — differentiable twin in PyTorch (float64), same numbers to rounding.

All of them walk the chain with :mod:`hykin.kinematics.walk` (one per-joint step: the array-namespace
:func:`~hykin.kinematics.walk.chain_walk` for numpy/torch, its numba twin for the compiled kernels).

Joints are in rad (revolute) or m (prismatic); positions in m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chain import Chain, chain_of
from .chunks import run_chunked
from .robot import Robot
from .walk import HAVE_NUMBA, chain_walk, expand_joints, reduce_columns

__all__ = ["HAVE_NUMBA", "FKFrames", "fk", "fk_chain", "fk_frames", "fk_torch", "jacobian"]


def _as_joints(robot: Robot, q) -> tuple[np.ndarray, bool]:
    """``(N, dof)`` float64 joints (independent; or ``(N, n_chain)`` chain joints of a robot with mimic
    joints) and whether ``q`` was a single row."""
    q = np.asarray(q, dtype=np.float64)
    single = q.ndim == 1
    q2 = np.ascontiguousarray(q.reshape(1, -1) if single else q)
    if q2.ndim != 2 or q2.shape[1] not in (robot.dof, robot.n_chain):
        raise ValueError(f"joints must have shape (N, {robot.dof}) or ({robot.dof},), got {q.shape}")
    return q2, single


# --------------------------------------------------------------------------- numba kernels (batched)

_BLOCK = 256  # poses per block in the batched kernels (sin/cos buffer stays in L1)

if HAVE_NUMBA:
    import numba

    from .walk import fk_one, joint_step, sincos, store_top, top_rows

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def _fk_block(fixed, prismatic, q, k0, k1, sbuf, cbuf, out):  # pragma: no cover - compiled
        """Poses ``k0:k1``: vectorised sin/cos of the whole block first, then the chain per pose."""
        n = q.shape[1]
        qf = q.reshape(q.shape[0] * n)  # C-contiguous: a view
        j0 = k0 * n
        for j in range((k1 - k0) * n):  # one flat, vectorisable loop
            sbuf[j], cbuf[j] = sincos(qf[j0 + j])
        for t in range(k1 - k0):
            st = top_rows(fixed[0])
            for i in range(n):
                st = joint_step(st, fixed[i + 1], prismatic[i], qf[j0 + t * n + i], sbuf[t * n + i], cbuf[t * n + i])
            store_top(st, out[k0 + t])

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def _fk_batch_range(fixed, prismatic, q, out, k0, k1):  # pragma: no cover - compiled
        """Poses ``k0:k1`` of ``q``, block by block (:func:`hykin.kinematics.chunks.run_chunked` spreads
        the ranges over threads)."""
        n = q.shape[1]
        sbuf = np.empty(_BLOCK * n)
        cbuf = np.empty(_BLOCK * n)
        for b0 in range(k0, k1, _BLOCK):
            _fk_block(fixed, prismatic, q, b0, min(b0 + _BLOCK, k1), sbuf, cbuf, out)


_PARALLEL_MIN = 20_000  # below this, thread start-up costs more than it saves


def fk_chain(chain: Chain, q: np.ndarray) -> np.ndarray:
    """FK of a numpy :class:`Chain` for ``q`` ``(N, dof)`` (contiguous float64) -> ``(N, 4, 4)``."""
    fixed = np.ascontiguousarray(chain.fixed, dtype=np.float64)
    prism = np.ascontiguousarray(chain.prismatic, dtype=np.bool_)
    q = np.ascontiguousarray(expand_joints(np, chain, np.asarray(q, dtype=np.float64)))
    if not HAVE_NUMBA:
        return chain_walk(np, chain, q)
    out = np.empty((q.shape[0], 4, 4))
    run_chunked(_fk_batch_range, (fixed, prism, q, out), q.shape[0], min_chunk=_PARALLEL_MIN // 2)
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
                fk_one(fixed, ch.prismatic, q, out)
                if not _ONE_ENTRY and q.strides[0] == 8:
                    _ONE_ENTRY.extend(_native_entry(fixed, ch.prismatic, q, out))
            return out
        if ch.expand is not None and q.shape[0] == ch.n_independent:  # mimic joints: the same fast path
            return fk(robot, expand_joints(np, ch, q))
    q2, single = _as_joints(robot, q)
    T = fk_chain(ch, q2)
    return T[0] if single else T


_F64 = np.dtype(np.float64)
# Native entry point of ``fk_one`` for (C float64 3-D, C bool 1-D, C float64 1-D, C float64 2-D)
# arguments: calling it skips numba's per-call type dispatch (~0.5 µs). ``fk`` only uses it for
# arguments of exactly those types (chain arrays from ``build_chain``, contiguous float64 ``q``).
_ONE_ENTRY: list = []


def _native_entry(fixed, prismatic, q, out) -> list:
    try:
        sig = tuple(numba.typeof(a) for a in (fixed, prismatic, q, out))
        if any(getattr(t, "readonly", False) or t.layout != "C" for t in sig):
            return []
        return [fk_one.overloads[sig].entry_point]
    except Exception:  # noqa: BLE001 - numba internals changed: keep the dispatcher
        return []


# --------------------------------------------------------------------------- all frames


@dataclass
class FKFrames:
    """All frames of a batch, world coordinates, float64.

    joint: ``(N, n, 4, 4)`` joint frames (z = joint axis, origin on the axis); ``n`` = chain joints
    (``robot.n_chain``, mimic joints included).
    link: ``(N, n, 4, 4)`` link frames (DH/MDH frame i, URDF child link i); ``link[:, -1]`` is the flange.
    tcp: ``(N, 4, 4)`` TCP = flange · tool.
    """

    joint: np.ndarray
    link: np.ndarray
    tcp: np.ndarray


def fk_frames(robot: Robot, q) -> FKFrames:
    """Joint frames, link frames and TCP for ``q`` ``(N, dof)`` (see :class:`FKFrames`)."""
    q2, _ = _as_joints(robot, q)
    j, l, t = chain_walk(np, chain_of(robot), q2, frames=True)
    return FKFrames(joint=j, link=l, tcp=t)


def jacobian(robot: Robot, q, frames: FKFrames | None = None) -> np.ndarray:
    """Geometric Jacobian of the TCP, ``(N, 6, dof)``, rows ``[v (m per unit); ω (rad per unit)]``.

    World-frame velocities of the TCP point: column i is ``[z_i × (p − o_i); z_i]`` for a revolute
    joint and ``[z_i; 0]`` for a prismatic one; a mimic joint's column adds to its leader's, times
    its multiplier (:func:`~hykin.kinematics.walk.reduce_columns`).
    """
    q2, single = _as_joints(robot, q)
    fr = fk_frames(robot, q2) if frames is None else frames
    z = fr.joint[..., :3, 2]  # (N, n, 3)
    o = fr.joint[..., :3, 3]
    p = fr.tcp[:, None, :3, 3]
    prism = np.asarray([t == "prismatic" for t in robot.joint_type])
    Jv = np.where(prism[None, :, None], z, np.cross(z, p - o))
    Jw = np.where(prism[None, :, None], 0.0, z)
    J = reduce_columns(chain_of(robot), np.concatenate([Jv, Jw], axis=-1).transpose(0, 2, 1))
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
            tool=conv(ch.tool), prismatic=ch.prismatic, expand=ch.expand, n_independent=ch.n_independent,
        )
    return chain_walk(torch, chain, q, frames=frames)
