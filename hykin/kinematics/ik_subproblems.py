"""Paden–Kahan subproblems and rotation helpers for the closed-form IK (numpy and numba twins).

* subproblem 1 (:func:`sp1`): the angle rotating one vector onto another about an axis;
* subproblem 4 (:func:`sp4`): both angles giving a prescribed projection ``h · R(k, θ) p = d``.

The numpy functions broadcast over leading axes (``(..., 3)`` vectors); the compiled twins
(``n``-prefixed, and the ``v*`` 3-tuple helpers) work on one case and are used by the per-target
kernels of :mod:`hykin.kinematics.ik_families`. Angles in rad.
"""

from __future__ import annotations

import numpy as np

from .walk import HAVE_NUMBA

__all__ = ["SP4_ATOL", "both_roots", "dot", "perpendicular", "rot", "rotmat", "sp1", "sp4"]

SP4_ATOL = np.inf  # how far beyond |cos| = 1 a subproblem-4 root is still clamped (see sp4)


def rot(k, th, v):
    """Rotate vectors ``v`` about unit axes ``k`` by ``th`` (Rodrigues); all broadcast, ``(..., 3)``."""
    c = np.cos(th)[..., None]
    s = np.sin(th)[..., None]
    kv = np.sum(k * v, axis=-1, keepdims=True)
    return v * c + np.cross(k, v) * s + k * kv * (1.0 - c)


def rotmat(k, th):
    """Rotation matrices ``(..., 3, 3)`` about unit axis ``k`` (3,) by angles ``th`` (...)."""
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    c = np.cos(th)[..., None, None]
    s = np.sin(th)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def dot(a, b):
    """Dot products over the last axis, broadcast."""
    return np.sum(a * b, axis=-1)


def sp1(p, q, k):
    """Angle θ rotating ``p`` onto ``q`` about unit ``k`` (components ⟂ k); 0 when degenerate
    (both vectors along ``k`` to rounding: the singular cases of the module docstring)."""
    y = dot(k, np.cross(p, q))
    x = dot(p, q) - dot(k, p) * dot(k, q)
    return np.where(np.hypot(x, y) < 1e-20, 0.0, np.arctan2(y, x))


def sp4(h, p, k, d, atol=np.inf):
    """Both roots θ of ``h · R(k, θ) p = d`` -> ``(θ+ , θ-)``, NaN where no real root.

    Cases without a real root (|d'/r| > 1: out of reach, or rounding near elbow/wrist singularities)
    are clamped to the nearest double root up to ``atol`` (default: always); the FK check and the
    refinement of :func:`hykin.kinematics.ik.ik_closed_form` then decide whether the candidate is a
    solution. Degenerate cases (amplitude ~ 0, e.g. shoulder/wrist singular) give θ = 0 when the equation holds.
    """
    kp = dot(k, p)[..., None] * k
    p_perp = p - kp
    A = dot(h, p_perp)
    B = dot(h, np.cross(k, p))
    C = d - dot(h, kp)
    r = np.hypot(A, B)
    scale = np.maximum(np.abs(C), 1.0)
    degenerate = r < 1e-12 * scale
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = C / np.where(degenerate, 1.0, r)
    ok = np.abs(ratio) <= 1.0 + atol
    a = np.arccos(np.clip(ratio, -1.0, 1.0))
    phi = np.arctan2(B, A)
    t1 = np.where(ok, phi + a, np.nan)
    t2 = np.where(ok, phi - a, np.nan)
    deg_ok = degenerate & (np.abs(C) < 1e-9 * scale)
    t1 = np.where(degenerate, np.where(deg_ok, 0.0, np.nan), t1)
    t2 = np.where(degenerate, np.where(deg_ok, 0.0, np.nan), t2)
    return t1, t2


def both_roots(t1, t2, axis):
    """The two roots of a subproblem stacked along a new ``axis`` (root 0 first)."""
    return np.stack([t1, t2], axis=axis)


def perpendicular(k):
    """A unit vector ``(3,)`` perpendicular to unit ``k`` ``(3,)`` (fixed choice, for angle references)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(k[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    v = np.cross(k, a)
    return v / np.linalg.norm(v)


# --------------------------------------------------------------------------- compiled twins

if HAVE_NUMBA:
    import numba

    __all__ += ["mv", "nsp1", "nsp4", "v3", "vadd", "vcross", "vdot", "vrot", "vrot_cs", "vsub"]

    _nj = numba.njit(cache=True, nogil=True)

    @_nj
    def v3(a):  # pragma: no cover - compiled
        """Vector ``(3,)`` array -> 3-tuple."""
        return (a[0], a[1], a[2])

    @_nj
    def vdot(a, b):  # pragma: no cover - compiled
        """Dot product of 3-tuples."""
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]

    @_nj
    def vcross(a, b):  # pragma: no cover - compiled
        """Cross product of 3-tuples."""
        return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])

    @_nj
    def vsub(a, b):  # pragma: no cover - compiled
        """``a - b`` of 3-tuples."""
        return (a[0] - b[0], a[1] - b[1], a[2] - b[2])

    @_nj
    def vadd(a, b):  # pragma: no cover - compiled
        """``a + b`` of 3-tuples."""
        return (a[0] + b[0], a[1] + b[1], a[2] + b[2])

    @_nj
    def vrot(k, th, v):  # pragma: no cover - compiled
        """``v`` rotated about unit ``k`` by ``th`` rad (Rodrigues), 3-tuples."""
        c, s = np.cos(th), np.sin(th)
        kv = vdot(k, v) * (1.0 - c)
        kx = vcross(k, v)
        return (v[0] * c + kx[0] * s + k[0] * kv, v[1] * c + kx[1] * s + k[1] * kv, v[2] * c + kx[2] * s + k[2] * kv)

    @_nj
    def vrot_cs(k, c, s, v):  # pragma: no cover - compiled
        """:func:`vrot` with ``c, s = cos th, sin th`` given."""
        kv = vdot(k, v) * (1.0 - c)
        kx = vcross(k, v)
        return (v[0] * c + kx[0] * s + k[0] * kv, v[1] * c + kx[1] * s + k[1] * kv, v[2] * c + kx[2] * s + k[2] * kv)

    @_nj
    def mv(M, v):  # pragma: no cover - compiled
        """``M @ v`` for ``M`` (3, 3) and a 3-tuple."""
        return (
            M[0, 0] * v[0] + M[0, 1] * v[1] + M[0, 2] * v[2],
            M[1, 0] * v[0] + M[1, 1] * v[1] + M[1, 2] * v[2],
            M[2, 0] * v[0] + M[2, 1] * v[1] + M[2, 2] * v[2],
        )

    @_nj
    def nsp1(p, q, k):  # pragma: no cover - compiled
        """Compiled :func:`sp1` for one triple of 3-tuples."""
        y = vdot(k, vcross(p, q))
        x = vdot(p, q) - vdot(k, p) * vdot(k, q)
        if np.hypot(x, y) < 1e-20:
            return 0.0
        return np.arctan2(y, x)

    @_nj
    def nsp4(h, p, k, d):  # pragma: no cover - compiled
        """Compiled :func:`sp4` for one case: ``(θ+, θ-, ok)``; NaN and ``ok = False`` where no root."""
        kp = vdot(k, p)
        A = vdot(h, p) - vdot(h, k) * kp
        B = vdot(h, vcross(k, p))
        C = d - vdot(h, k) * kp
        r = np.hypot(A, B)
        scale = max(abs(C), 1.0)
        if r < 1e-12 * scale:
            if abs(C) < 1e-9 * scale:
                return 0.0, 0.0, True
            return np.nan, np.nan, False
        ratio = C / r
        if abs(ratio) > 1.0 + SP4_ATOL:
            return np.nan, np.nan, False
        ratio = min(1.0, max(-1.0, ratio))
        a = np.arccos(ratio)
        phi = np.arctan2(B, A)
        return phi + a, phi - a, True
