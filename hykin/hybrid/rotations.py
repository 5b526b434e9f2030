"""Rotations the hybrid model applies: the orientation correction ``exp(Δr)`` on poses and the
turn of residual vectors about the joint-1 axis (network frame with ``joint1="frame"``)."""

from __future__ import annotations

import numpy as np
import torch

from ..kinematics.chunks import run_chunked
from ..kinematics.fk import HAVE_NUMBA

__all__ = ["rodrigues", "rotate_about", "rotate_poses"]


def rodrigues(rv: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(N, 3)`` (rad) -> rotation matrices ``(N, 3, 3)`` (vectorised, Taylor-safe near 0)."""
    th2 = np.einsum("ij,ij->i", rv, rv)
    th = np.sqrt(th2)
    small = th2 < 1e-8
    ths = np.where(small, 1.0, th)
    A = np.where(small, 1 - th2 / 6, np.sin(ths) / ths)
    B = np.where(small, 0.5 - th2 / 24, (1 - np.cos(ths)) / np.where(small, 1.0, th2))
    x, y, z = rv[:, 0], rv[:, 1], rv[:, 2]
    K = np.zeros((rv.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -z, y, z, -x, -y, x
    return np.eye(3) + A[:, None, None] * K + B[:, None, None] * (K @ K)


if HAVE_NUMBA:
    import numba

    @numba.njit(cache=True, nogil=True)
    def rotate_top(x, y, z, T):  # pragma: no cover
        """In place ``T[:3, :3] = exp([x, y, z]) @ T[:3, :3]`` for one pose (same formula as :func:`rodrigues`)."""
        th2 = x * x + y * y + z * z
        if th2 < 1e-8:
            A = 1 - th2 / 6
            B = 0.5 - th2 / 24
        else:
            th = np.sqrt(th2)
            A = np.sin(th) / th
            B = (1 - np.cos(th)) / th2
        # R = I + A K + B K^2, K = [[0, -z, y], [z, 0, -x], [-y, x, 0]]
        r00 = 1 + B * (-z * z - y * y)
        r01 = -A * z + B * (x * y)
        r02 = A * y + B * (x * z)
        r10 = A * z + B * (x * y)
        r11 = 1 + B * (-z * z - x * x)
        r12 = -A * x + B * (y * z)
        r20 = -A * y + B * (x * z)
        r21 = A * x + B * (y * z)
        r22 = 1 + B * (-y * y - x * x)
        for c in range(3):
            t0, t1, t2 = T[0, c], T[1, c], T[2, c]
            T[0, c] = r00 * t0 + r01 * t1 + r02 * t2
            T[1, c] = r10 * t0 + r11 * t1 + r12 * t2
            T[2, c] = r20 * t0 + r21 * t1 + r22 * t2

    @numba.njit(cache=True, nogil=True)
    def _rotate_range(rv, T, k0, k1):  # pragma: no cover
        """In place ``T[k, :3, :3] = exp(rv[k]) @ T[k, :3, :3]`` for rows ``k0:k1``."""
        for k in range(k0, k1):
            rotate_top(rv[k, 0], rv[k, 1], rv[k, 2], T[k])


#: rows at least this many are spread over the worker threads (~25 ns a row)
_PARALLEL_MIN = 40_000


def rotate_poses(dr: np.ndarray, T: np.ndarray) -> None:
    """In place ``T[:, :3, :3] = exp(dr) @ T[:, :3, :3]`` for rotation vectors ``dr`` ``(N, 3)`` (rad)
    and poses ``T`` ``(N, 4, 4)`` (numba kernel when available and ``T`` is contiguous)."""
    if HAVE_NUMBA and T.flags.c_contiguous:
        run_chunked(_rotate_range, (np.ascontiguousarray(dr), T), len(T), min_chunk=_PARALLEL_MIN // 2)
    else:
        T[:, :3, :3] = rodrigues(dr) @ T[:, :3, :3]


def rotate_about(u: np.ndarray, angle, v):
    """Rotate vectors ``v`` ``(N, 3)`` about the unit axis ``u`` ``(3,)`` by ``angle`` ``(N,)`` (rad;
    numpy or torch)."""
    if isinstance(v, torch.Tensor):
        ut = torch.as_tensor(u, dtype=v.dtype, device=v.device)
        c, s = torch.cos(angle)[:, None], torch.sin(angle)[:, None]
        cross = torch.cross(ut.expand_as(v), v, dim=1)
        return v * c + cross * s + ut * (v @ ut)[:, None] * (1 - c)
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * c + np.cross(u, v) * s + u * (v @ u)[:, None] * (1 - c)
