"""Forward kinematics and geometric Jacobians, batched over ``(N, dof)`` joint arrays, float64.

* :func:`fk` — TCP poses in the world frame ``(N, 4, 4)``; a compiled (numba) kernel when numba is
  installed, a vectorised numpy fallback otherwise. Same numbers either way.
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

__all__ = ["fk", "fk_chain", "fk_frames", "FKFrames", "jacobian", "fk_torch", "HAVE_NUMBA"]

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

if HAVE_NUMBA:

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def _fk_one(fixed, prismatic, q, out):  # pragma: no cover - compiled
        n = q.shape[0]
        T = np.empty((3, 4))
        for r in range(3):
            for c in range(4):
                T[r, c] = fixed[0, r, c]
        for i in range(n):
            if prismatic[i]:
                for r in range(3):
                    T[r, 3] += T[r, 2] * q[i]
            else:
                cq, sq = np.cos(q[i]), np.sin(q[i])
                for r in range(3):
                    x, y = T[r, 0], T[r, 1]
                    T[r, 0] = cq * x + sq * y
                    T[r, 1] = cq * y - sq * x
            F = fixed[i + 1]
            for r in range(3):
                t0, t1, t2, t3 = T[r, 0], T[r, 1], T[r, 2], T[r, 3]
                for c in range(4):
                    v = t0 * F[0, c] + t1 * F[1, c] + t2 * F[2, c]
                    if c == 3:
                        v += t3
                    T[r, c] = v
        for r in range(3):
            for c in range(4):
                out[r, c] = T[r, c]
        out[3, 0] = 0.0
        out[3, 1] = 0.0
        out[3, 2] = 0.0
        out[3, 3] = 1.0

    @numba.njit(cache=True, nogil=True)
    def _fk_batch_serial(fixed, prismatic, q, out):  # pragma: no cover - compiled
        for k in range(q.shape[0]):
            _fk_one(fixed, prismatic, q[k], out[k])

    @numba.njit(cache=True, nogil=True, parallel=True)
    def _fk_batch_parallel(fixed, prismatic, q, out):  # pragma: no cover - compiled
        for k in numba.prange(q.shape[0]):
            _fk_one(fixed, prismatic, q[k], out[k])


_PARALLEL_MIN = 20_000  # below this, thread start-up costs more than it saves


def fk_chain(chain: Chain, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """FK of a numpy :class:`Chain` for ``q`` ``(N, dof)`` (contiguous float64) -> ``(N, 4, 4)``."""
    fixed = np.ascontiguousarray(chain.fixed, dtype=np.float64)
    prism = np.ascontiguousarray(chain.prismatic, dtype=np.bool_)
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
    """
    q2, single = _as_joints(robot.dof, q)
    T = fk_chain(chain_of(robot), q2)
    return T[0] if single else T


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
        conv = lambda x: torch.as_tensor(x, dtype=q.dtype, device=q.device)  # noqa: E731
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
