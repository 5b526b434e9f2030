"""Closed-form IK of the two supported 6R families: all 8 candidate joint vectors per target.

* :func:`solve_opw` / :func:`opw_one` — spherical wrist, axes 2 ∥ 3 (``"opw"``);
* :func:`solve_ur` / :func:`ur_one` — axes 2 ∥ 3 ∥ 4, axes 5 and 6 intersecting (``"ur"``).

Branch ``b = 4·i + 2·j + k`` (shoulder, elbow, wrist roots; see :mod:`hykin.kinematics.ik_closed_form`).
The numpy solvers are batched over targets and are the reference; the compiled ones (numba) do the
same algebra for one target. Both work on the POE model (:class:`hykin.kinematics.poe.POEModel`).
Angles in rad, lengths in m.
"""

from __future__ import annotations

import numpy as np

from .ik_subproblems import both_roots, dot, perpendicular, rot, rotmat, sp1, sp4
from .poe import POEModel
from .walk import HAVE_NUMBA

__all__ = ["solve_opw", "solve_ur"]


def solve_opw(m: POEModel, R_t, p_t):
    """All 8 candidates ``(N, 2, 2, 2, 6)`` for the spherical-wrist family (NaN = no root)."""
    h, p = m.h, m.p
    R0, P0 = m.T0[:3, :3], m.T0[:3, 3]
    W0 = m.wc
    Rd = R_t @ R0.T  # (N,3,3)
    W = p_t + Rd @ (W0 - P0)  # wrist centre of the target, (N,3)
    # q1: h2 . R1^T (W - p1) = h2 . (W0 - p1)
    t1a, t1b = sp4(W - p[0], h[1], h[0], np.full(len(W), h[1] @ (W0 - p[0])))
    q1 = both_roots(t1a, t1b, 1)  # (N,2)
    Wl = p[0] + rot(h[0], -q1, (W - p[0])[:, None, :])  # (N,2,3): wrist centre with joint 1 undone
    c = p[2] - p[1]
    u = W0 - p[2]
    D2 = dot(Wl - p[1], Wl - p[1])
    t3a, t3b = sp4(c, u, h[2], (D2 - c @ c - u @ u) / 2.0)
    q3 = both_roots(t3a, t3b, 2)  # (N,2,2)
    e3W0 = p[2] + rot(h[2], q3, u)  # (N,2,2,3)
    q2 = sp1(e3W0 - p[1], (Wl - p[1])[:, :, None, :], h[1])  # (N,2,2)
    # wrist: R4 R5 R6 = Rw = (R1 R2 R3)^T Rd
    R123 = rotmat(h[0], q1)[:, :, None] @ rotmat(h[1], q2) @ rotmat(h[2], q3)  # (N,2,2,3,3)
    Rw = np.swapaxes(R123, -1, -2) @ Rd[:, None, None]
    v = Rw @ h[5]  # (N,2,2,3)
    t5a, t5b = sp4(h[3], h[5], h[4], v @ h[3])
    q5 = both_roots(t5a, t5b, 3)  # (N,2,2,2)
    R5h6 = rot(h[4], q5, h[5])
    q4 = sp1(R5h6, v[:, :, :, None, :], h[3])
    x = perpendicular(h[5])
    Rw_x = (Rw @ x)[:, :, :, None, :]
    y = rot(h[4], -q5, rot(h[3], -q4, Rw_x))
    q6 = sp1(x, y, h[5])
    sh = q5.shape
    return np.stack(
        [np.broadcast_to(q1[:, :, None, None], sh), np.broadcast_to(q2[..., None], sh),
         np.broadcast_to(q3[..., None], sh), q4, q5, q6], axis=-1,
    )


def solve_ur(m: POEModel, R_t, p_t):
    """All 8 candidates ``(N, 2, 2, 2, 6)`` for the three-parallel-axes family (branch order i, j=q3, k=q5)."""
    h, p = m.h, m.p
    R0, P0 = m.T0[:3, :3], m.T0[:3, 3]
    N = len(p_t)
    Rd = R_t @ R0.T
    P56 = m.wc
    p6w = p_t + Rd @ (P56 - P0)  # (N,3)
    t1a, t1b = sp4(p6w - p[0], h[1], h[0], np.full(N, h[1] @ (P56 - p[0])))
    q1 = both_roots(t1a, t1b, 1)  # (N,2)
    R1h2 = rot(h[0], q1, h[1])  # (N,2,3)
    d5 = dot(R1h2, (Rd @ h[5])[:, None, :])
    t5a, t5b = sp4(h[1], h[5], h[4], d5)
    q5 = both_roots(t5a, t5b, 2)  # (N,2,2)  (index: i, k)
    # q6: R(h6, q6) (Rd^T R1 h2) = R5^T h2
    a6 = (np.swapaxes(Rd, -1, -2)[:, None] @ R1h2[..., None])[..., 0]  # (N,2,3)
    b6 = rot(h[4], -q5, h[1])  # (N,2,2,3)
    q6 = sp1(a6[:, :, None, :], b6, h[5])  # (N,2,2)
    # theta234 about h2: R234 = R1^T Rd R6^T R5^T
    x = perpendicular(h[1])
    y = rot(h[4], -q5, x)
    y = rot(h[5], -q6, y)
    y = (Rd[:, None, None] @ y[..., None])[..., 0]
    y = rot(h[0], -q1[:, :, None], y)
    th = sp1(x, y, h[1])  # (N,2,2)
    # position: e2 e3 (p4) = e1^{-1}(p_t) - R234 (Z - p4), Z = e5 e6 (P0)
    Z = p[5] + rot(h[5], q6, P0 - p[5])
    Z = p[4] + rot(h[4], q5, Z - p[4])  # (N,2,2,3)
    pl = p[0] + rot(h[0], -q1, (p_t - p[0])[:, None, :])  # (N,2,3)
    W = pl[:, :, None, :] - rot(h[1], th, Z - p[3])  # (N,2,2,3)
    c = p[2] - p[1]
    u = p[3] - p[2]
    D2 = dot(W - p[1], W - p[1])
    t3a, t3b = sp4(c, u, h[2], (D2 - c @ c - u @ u) / 2.0)
    q3 = both_roots(t3a, t3b, 2)  # (N,2,2j,2k)
    e3p4 = p[2] + rot(h[2], q3, u)
    q2 = sp1(e3p4 - p[1], (W - p[1])[:, :, None, :, :], h[1])
    s3, s4 = h[2] @ h[1], h[3] @ h[1]
    q4 = s4 * (th[:, :, None, :] - q2 - s3 * q3)
    sh = q3.shape
    return np.stack(
        [np.broadcast_to(q1[:, :, None, None], sh), q2, q3, q4,
         np.broadcast_to(q5[:, :, None, :], sh), np.broadcast_to(q6[:, :, None, :], sh)], axis=-1,
    )


# --------------------------------------------------------------------------- compiled, one target

if HAVE_NUMBA:
    import numba

    from .ik_subproblems import mv, nsp1, nsp4, v3, vadd, vdot, vrot, vrot_cs, vsub

    __all__ += ["opw_one", "ur_one"]

    @numba.njit(cache=True, nogil=True)
    def opw_one(h, p, Rd, W, W0, x6, out, ok):  # pragma: no cover - compiled
        """:func:`solve_opw` of one target: ``Rd`` (3, 3) target rotation times ``R0ᵀ``, ``W`` its wrist
        centre, ``W0`` the zero-pose one, ``x6`` ⟂ axis 6; writes ``out`` (8, 6) and ``ok`` (8,)."""
        h1, h2, h3, h4, h5, h6 = v3(h[0]), v3(h[1]), v3(h[2]), v3(h[3]), v3(h[4]), v3(h[5])
        p1, p2, p3 = v3(p[0]), v3(p[1]), v3(p[2])
        a1, b1, f1 = nsp4(vsub(W, p1), h2, h1, vdot(h2, vsub(W0, p1)))
        c = vsub(p3, p2)
        u = vsub(W0, p3)
        cc, uu = vdot(c, c), vdot(u, u)
        Rdh6 = mv(Rd, h6)
        Rdx = mv(Rd, x6)
        for i in range(2):
            q1 = a1 if i == 0 else b1
            c1, s1 = np.cos(q1), np.sin(q1)
            Wl = vadd(p1, vrot_cs(h1, c1, -s1, vsub(W, p1)))
            Wr = vsub(Wl, p2)
            a3, b3, f3 = nsp4(c, u, h3, (vdot(Wr, Wr) - cc - uu) / 2.0)
            v1 = vrot_cs(h1, c1, -s1, Rdh6)
            x1 = vrot_cs(h1, c1, -s1, Rdx)
            for j in range(2):
                q3 = a3 if j == 0 else b3
                c3, s3_ = np.cos(q3), np.sin(q3)
                e3 = vadd(c, vrot_cs(h3, c3, s3_, u))
                q2 = nsp1(e3, Wr, h2)
                c2, s2 = np.cos(q2), np.sin(q2)
                v = vrot_cs(h3, c3, -s3_, vrot_cs(h2, c2, -s2, v1))
                wx = vrot_cs(h3, c3, -s3_, vrot_cs(h2, c2, -s2, x1))
                a5, b5, f5 = nsp4(h4, h6, h5, vdot(v, h4))
                for k in range(2):
                    q5 = a5 if k == 0 else b5
                    c5, s5 = np.cos(q5), np.sin(q5)
                    q4 = nsp1(vrot_cs(h5, c5, s5, h6), v, h4)
                    y = vrot_cs(h5, c5, -s5, vrot(h4, -q4, wx))
                    q6 = nsp1(x6, y, h6)
                    b = 4 * i + 2 * j + k
                    out[b, 0], out[b, 1], out[b, 2] = q1, q2, q3
                    out[b, 3], out[b, 4], out[b, 5] = q4, q5, q6
                    ok[b] = f1 and f3 and f5

    @numba.njit(cache=True, nogil=True)
    def ur_one(h, p, Rd, p6w, pt, P56, P0, x2, s3, s4, out, ok):  # pragma: no cover - compiled
        """:func:`solve_ur` of one target: ``Rd`` (3, 3) target rotation times ``R0ᵀ``, ``p6w`` the target's
        axis-5/6 point, ``pt`` its TCP, ``P56``/``P0`` the zero-pose ones, ``x2`` ⟂ axis 2, ``s3``, ``s4`` axis
        signs relative to axis 2; writes ``out`` (8, 6) and ``ok`` (8,)."""
        h1, h2, h3, h5, h6 = v3(h[0]), v3(h[1]), v3(h[2]), v3(h[4]), v3(h[5])  # axis 4 ∥ 2: q4 from th
        p1, p2, p3, p4, p5, p6 = v3(p[0]), v3(p[1]), v3(p[2]), v3(p[3]), v3(p[4]), v3(p[5])
        a1, b1, f1 = nsp4(vsub(p6w, p1), h2, h1, vdot(h2, vsub(P56, p1)))
        Rdh6 = mv(Rd, h6)
        c = vsub(p3, p2)
        u = vsub(p4, p3)
        cc, uu = vdot(c, c), vdot(u, u)
        for i in range(2):
            q1 = a1 if i == 0 else b1
            c1, s1 = np.cos(q1), np.sin(q1)
            R1h2 = vrot_cs(h1, c1, s1, h2)
            a6v = (
                Rd[0, 0] * R1h2[0] + Rd[1, 0] * R1h2[1] + Rd[2, 0] * R1h2[2],
                Rd[0, 1] * R1h2[0] + Rd[1, 1] * R1h2[1] + Rd[2, 1] * R1h2[2],
                Rd[0, 2] * R1h2[0] + Rd[1, 2] * R1h2[1] + Rd[2, 2] * R1h2[2],
            )
            a5, b5, f5 = nsp4(h2, h6, h5, vdot(R1h2, Rdh6))
            pl = vadd(p1, vrot_cs(h1, c1, -s1, vsub(pt, p1)))
            for k in range(2):
                q5 = a5 if k == 0 else b5
                c5, s5 = np.cos(q5), np.sin(q5)
                q6 = nsp1(a6v, vrot_cs(h5, c5, -s5, h2), h6)
                c6, s6 = np.cos(q6), np.sin(q6)
                y = vrot_cs(h1, c1, -s1, mv(Rd, vrot_cs(h6, c6, -s6, vrot_cs(h5, c5, -s5, x2))))
                th = nsp1(x2, y, h2)
                Z = vadd(p6, vrot_cs(h6, c6, s6, vsub(P0, p6)))
                Z = vadd(p5, vrot_cs(h5, c5, s5, vsub(Z, p5)))
                W = vsub(pl, vrot(h2, th, vsub(Z, p4)))
                Wr = vsub(W, p2)
                a3, b3, f3 = nsp4(c, u, h3, (vdot(Wr, Wr) - cc - uu) / 2.0)
                for j in range(2):
                    q3 = a3 if j == 0 else b3
                    q2 = nsp1(vadd(c, vrot(h3, q3, u)), Wr, h2)
                    q4 = s4 * (th - q2 - s3 * q3)
                    b = 4 * i + 2 * j + k
                    out[b, 0], out[b, 1], out[b, 2] = q1, q2, q3
                    out[b, 3], out[b, 4], out[b, 5] = q4, q5, q6
                    ok[b] = f1 and f5 and f3
