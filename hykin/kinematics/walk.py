"""The chain walk: ``T = F_0 · J(q_1) · F_1 · J(q_2) ··· J(q_n) · F_n`` (see :mod:`hykin.kinematics.chain`).

One per-joint step, two backends of it:

* :func:`chain_walk` — written once over an array namespace ``xp`` (numpy or torch; torch keeps the
  autograd graph, so geometry built with ``build_chain(..., xp=torch)`` is differentiable). It serves
  :func:`hykin.kinematics.fk.fk_frames`, :func:`~hykin.kinematics.fk.fk_torch`, the numpy FK without
  numba, compliance and the numpy LM.
* numba (when installed): :func:`joint_step` is the same step on the top 3x4 rows of the running
  transform held in 12 scalars; :func:`fk_one` and :func:`axes_one` walk one configuration with it,
  and the batched FK kernels of :mod:`hykin.kinematics.fk`, the LM kernel and the closed-form
  kernels call these.

The step: joint i multiplies the running transform by ``J(q_i)`` — a rotation about its z axis
(revolute: columns x, y rotated by ``q_i``) or a translation along z (prismatic: origin moved by
``q_i`` times column z) — and then by the fused fixed transform ``F_i``. The running transform right
after ``J(q_i)`` is joint frame i; times ``post_i`` it is link frame i.
Joints in rad (revolute) or m (prismatic), lengths in m, float64.
"""

from __future__ import annotations

import numpy as np

__all__ = ["HAVE_NUMBA", "chain_walk", "expand_joints", "joint_motion", "reduce_columns"]

try:  # numba is optional: it makes single-pose FK ~50x and batched FK ~5x faster than numpy.
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised in environments without numba
    numba = None
    HAVE_NUMBA = False


def joint_motion(xp, T, qi, prismatic: bool):
    """``T · J(q_i)`` for a batch of transforms ``T`` ``(N, 4, 4)`` and joint values ``qi`` ``(N,)``.

    Revolute: ``x' = cos q · x + sin q · y``, ``y' = cos q · y − sin q · x`` (columns x, y of ``T``);
    prismatic: origin ``+= q · z``. Out of place (torch autograd), namespace ``xp``.
    """
    x, y, z, o = T[..., :, 0], T[..., :, 1], T[..., :, 2], T[..., :, 3]
    if prismatic:
        return xp.stack([x, y, z, o + z * qi[..., None]], -1)
    c, s = xp.cos(qi)[..., None], xp.sin(qi)[..., None]
    return xp.stack([c * x + s * y, c * y - s * x, z, o], -1)


def expand_joints(xp, chain, q):
    """Chain joints ``(N, n_chain)`` from ``q``: THE one place where mimic joints enter the chain.

    ``q`` ``(N, dof)`` independent joints -> ``q_chain[:, i] = multiplier_i · q[:, index_i] + offset_i``
    (URDF ``<mimic>``, ``chain.expand``). ``q`` that already has ``n_chain`` columns (chain joints, e.g.
    deflected joints from :mod:`hykin.kinematics.compliance`) and every chain without mimic joints
    pass through unchanged (for a robot with mimic joints ``dof < n_chain``, so the width says which
    it is). numpy or torch (``xp``), differentiable.
    """
    ex = chain.expand
    if ex is None or q.shape[-1] == chain.prismatic.shape[0]:
        return q
    idx, mult, off = ex
    if xp is np:
        return q[..., idx] * mult + off
    conv = lambda a: xp.as_tensor(a, dtype=q.dtype, device=q.device)
    return q[..., xp.as_tensor(idx, device=q.device)] * conv(mult) + conv(off)


def reduce_columns(chain, J):
    """Chain rule for mimic joints: columns per chain joint ``(..., n_chain)`` -> per independent joint
    ``(..., dof)``; a leader's column sums ``multiplier ·`` its followers' columns. The transpose of
    :func:`expand_joints` (numpy); unchanged without mimic joints."""
    ex = chain.expand
    if ex is None:
        return J
    idx, mult, _ = ex
    E = np.zeros((idx.shape[0], int(idx.max()) + 1))
    E[np.arange(idx.shape[0]), idx] = mult
    return J @ E


def chain_walk(xp, chain, q, frames: bool = False):
    """Walk ``chain`` (a :class:`~hykin.kinematics.chain.Chain`) for joints ``q`` ``(N, dof)``
    (independent joints, expanded by :func:`expand_joints`) or ``(N, n_chain)`` (chain joints).

    Returns the TCP poses ``(N, 4, 4)`` in the world frame, or with ``frames=True``
    ``(joint frames (N, n_chain, 4, 4), link frames (N, n_chain, 4, 4), tcp (N, 4, 4))``. ``xp``: ``numpy``
    (numpy chain and ``q``) or ``torch`` (tensors of one dtype/device; differentiable).
    """
    q = expand_joints(xp, chain, q)
    N, n = q.shape
    T = xp.broadcast_to(chain.fixed[0], (N, 4, 4))
    joints, links = [], []
    for i in range(n):
        T = joint_motion(xp, T, q[:, i], bool(chain.prismatic[i]))
        if frames:
            joints.append(T)
            links.append(T @ chain.post[i])
        T = T @ chain.fixed[i + 1]
    if frames:
        return xp.stack(joints, 1), xp.stack(links, 1), T
    return T


# --------------------------------------------------------------------------- numba backend

# Cephes sin/cos (Moshier): reduction by pi/4 in three parts, minimax polynomials; |error| <= 2.3e-16
# for the joint ranges of robots (|q| < 1e6 rad). Unlike libm calls, these loops vectorise (AVX2: ~4 ns
# per sin/cos pair instead of ~35 ns), which makes trigonometry a small part of FK. Results differ
# from libm's by at most one unit in the last place.
_DP1 = 7.85398125648498535156e-1
_DP2 = 3.77489470793079817668e-8
_DP3 = 2.69515142907905952645e-15
_FOUR_OVER_PI = 1.27323954473516268615

if HAVE_NUMBA:
    __all__ += [
        "axes_one", "fk_one", "joint_motion_top", "joint_step", "sincos", "store_top", "times_fixed", "top_rows",
    ]

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def sincos(x):  # pragma: no cover - compiled
        """``(sin x, cos x)`` of a float (rad), branch-free so that loops over it vectorise."""
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
    def top_rows(F):  # pragma: no cover - compiled
        """The top 3x4 rows of a ``(4, 4)`` transform as 12 scalars (row-major): the walk's state."""
        return (F[0, 0], F[0, 1], F[0, 2], F[0, 3], F[1, 0], F[1, 1], F[1, 2], F[1, 3],
                F[2, 0], F[2, 1], F[2, 2], F[2, 3])

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def joint_motion_top(st, prism, qi, sq, cq):  # pragma: no cover - compiled
        """Walk state ``st`` (12 scalars, :func:`top_rows`) times ``J(q_i)``: the joint frame; ``sq, cq =
        sincos(qi)``. The compiled twin of :func:`joint_motion`."""
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
        return a0, a1, a2, a3, b0, b1, b2, b3, c0, c1, c2, c3

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def times_fixed(st, F):  # pragma: no cover - compiled
        """Walk state ``st`` (12 scalars) times a fixed transform ``F`` (4, 4) (bottom row ``[0, 0, 0, 1]``)."""
        a0, a1, a2, a3, b0, b1, b2, b3, c0, c1, c2, c3 = st
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
    def joint_step(st, F, prism, qi, sq, cq):  # pragma: no cover - compiled
        """One step of the walk: state ``st`` times ``J(q_i)`` times the fused fixed transform ``F``."""
        return times_fixed(joint_motion_top(st, prism, qi, sq, cq), F)

    @numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
    def store_top(st, out):  # pragma: no cover - compiled
        """Write walk state ``st`` into ``out`` ``(4, 4)`` with bottom row ``[0, 0, 0, 1]``."""
        out[0, 0], out[0, 1], out[0, 2], out[0, 3] = st[0], st[1], st[2], st[3]
        out[1, 0], out[1, 1], out[1, 2], out[1, 3] = st[4], st[5], st[6], st[7]
        out[2, 0], out[2, 1], out[2, 2], out[2, 3] = st[8], st[9], st[10], st[11]
        out[3, 0] = 0.0
        out[3, 1] = 0.0
        out[3, 2] = 0.0
        out[3, 3] = 1.0

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def fk_one(fixed, prismatic, q, out):  # pragma: no cover - compiled
        """TCP pose of one configuration ``q`` ``(n,)`` into ``out`` ``(4, 4)``; ``fixed`` ``(n + 1, 4, 4)``,
        ``prismatic`` ``(n,)`` bool (a chain's arrays). Same numbers as the batched FK kernels."""
        st = top_rows(fixed[0])
        for i in range(q.shape[0]):
            sq, cq = sincos(q[i])
            st = joint_step(st, fixed[i + 1], prismatic[i], q[i], sq, cq)
        store_top(st, out)

    @numba.njit(cache=True, nogil=True)
    def axes_one(fixed, prismatic, q, z, o, T):  # pragma: no cover - compiled
        """Joint axes ``z`` (n, 3), axis origins ``o`` (n, 3) and TCP top rows ``T`` (3, 4) of one
        configuration ``q`` (n,), world frame (what a geometric Jacobian needs)."""
        st = top_rows(fixed[0])
        for i in range(q.shape[0]):
            # J(q_i) turns about / slides along z through o: both are those of the state before it
            z[i, 0], z[i, 1], z[i, 2] = st[2], st[6], st[10]
            o[i, 0], o[i, 1], o[i, 2] = st[3], st[7], st[11]
            sq, cq = sincos(q[i])
            st = joint_step(st, fixed[i + 1], prismatic[i], q[i], sq, cq)
        for r in range(3):
            for c in range(4):
                T[r, c] = st[4 * r + c]
