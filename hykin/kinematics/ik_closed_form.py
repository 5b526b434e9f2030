"""Closed-form inverse kinematics returning every solution branch, batched over targets.

This module: which robots have a closed form (:func:`has_closed_form`) and the 8 candidate branches
per target with limit wrapping, FK check and duplicate removal (:func:`closed_form_candidates`).
The POE model is in :mod:`hykin.kinematics.poe`, the subproblems in
:mod:`hykin.kinematics.ik_subproblems`, the two family solvers in :mod:`hykin.kinematics.ik_families`;
the public :func:`hykin.kinematics.ik.ik_closed_form` adds the LM refinement of near-singular
candidates (LM lives in :mod:`hykin.kinematics.ik`, which calls this module, never the other way).

Two families of 6R arms are solved exactly (up to 8 solutions each):

* ``"opw"`` — spherical wrist (axes 4, 5, 6 meet in one point) and parallel axes 2 ∥ 3, with axis 1
  not parallel to axis 2. This contains the ortho-parallel basis with spherical wrist of
  Brandstötter et al. (2014) — Stäubli RX160, KUKA KR, ABB IRB, Fanuc — and also non-orthogonal
  variants of it.
* ``"ur"`` — three parallel axes 2 ∥ 3 ∥ 4, axes 5 and 6 intersecting, axis 1 and axis 5 not
  parallel to axis 2 (Universal Robots UR3/5/10/16, e-series; Hawkins 2013).

How: the robot is turned into its product-of-exponentials (POE) form at ``q = 0`` in the *world*
frame — unit axis ``h_i`` and a point ``p_i`` on each joint axis plus the zero-pose TCP ``T0``:
``T(q) = e_1(q_1) ··· e_6(q_6) · T0``. This representation is convention free: DH, MDH or URDF,
base and tool frames, theta offsets and axis signs are all absorbed, so no per-vendor parameter
table (``a1, a2, b, c1..c4``, offsets, signs) has to be extracted. The structure test is geometric
(parallel / intersecting axes to ``tol``) and the extracted POE model is verified against
:func:`hykin.kinematics.fk.fk` on random joints; the robot is rejected (``None``) otherwise. The joint
angles follow from the Paden–Kahan subproblems 1 (rotation of a point onto another) and 4 (rotation
giving a prescribed projection; subproblems 2 and 3 reduce to it), as in ik-geo (Elias & Wen 2022).

Branches and representation (decisions, documented):

* Branch index ``b = 4·i + 2·j + k`` with ``i`` the root of joint 1 (shoulder), ``j`` the root of the
  elbow joint (3 for ``opw``, 3 for ``ur``), ``k`` the root of the wrist (5). Root 0 is ``φ + acos``,
  root 1 is ``φ − acos`` of the underlying subproblem: labels read e.g. ``"shoulder+ elbow- wrist+"``.
* Each branch is returned **once**, in the representation nearest zero that lies within the joint
  limits (joints with a range over 2π are tried at ``q ± 2πk``); two joint vectors that differ by
  multiples of 2π count as one solution. Exhaustive numerical searches must count the same way.
* A branch is ``valid`` only if all joints are within limits, FK reproduces the target to
  ``tol_m`` / ``tol_rad`` and it is not a duplicate (modulo 2π) of an earlier valid branch (double
  roots at workspace boundaries and singularities).
* Singular cases: wrist singular (axes 4 and 6 aligned, e.g. ``q5 = 0`` on an RX160; ``ur``: axis 6
  parallel to axes 2–4) -> joint 4 (``ur``: joint 6) is set to 0 and the other wrist joint takes the
  whole rotation; shoulder singular (wrist centre on axis 1) -> joint 1 is set to 0. Exactly at a
  singularity the solutions form a continuum and only these representatives are returned; for a
  ``ur`` arm at an exact wrist singularity with the elbow stretched, ``q6 = 0`` may leave the target
  out of reach, so no branch is valid (:func:`hykin.kinematics.ik.ik` then falls back to LM). Near (not at) a
  singularity the roots are computed normally; rounding decides the free angle.
"""

from __future__ import annotations

import numpy as np

from .chain import chain_of
from .chunks import run_chunked
from .fk import fk
from .ik_families import solve_opw, solve_ur
from .ik_solutions import (
    TWO_PI,
    IKSolutions,
    mark_duplicates,
    pose_residual,
    wrap_to_limits,
)
from .ik_subproblems import perpendicular
from .poe import poe_model
from .robot import Robot
from .walk import HAVE_NUMBA

__all__ = ["BRANCH_LABELS", "ClosedFormError", "closed_form_candidates", "has_closed_form"]

# label of branch b = 4·i + 2·j + k: root i of the shoulder, j of the elbow, k of the wrist (0 = "+")
BRANCH_LABELS = tuple(f"shoulder{'+-'[b >> 2]} elbow{'+-'[(b >> 1) & 1]} wrist{'+-'[b & 1]}" for b in range(8))


class ClosedFormError(ValueError):
    """The robot has no closed-form IK of a supported family (message says which test failed)."""


def has_closed_form(robot: Robot, tol: float = 1e-9) -> str | None:
    """``"opw"`` or ``"ur"`` when :func:`hykin.kinematics.ik.ik_closed_form` applies to ``robot``, else ``None``."""
    return poe_model(robot, tol).family


def closed_form_candidates(robot: Robot, T: np.ndarray, tol_m: float = 1e-9, tol_rad: float = 1e-9,
                           structure_tol: float = 1e-9, use_numba: bool = True) -> IKSolutions:
    """The 8 closed-form branches of world TCP targets ``T`` ``(N, 4, 4)`` (validated, see
    :func:`hykin.kinematics.ik_solutions.as_targets`), before refinement.

    Raises :class:`ClosedFormError` when the robot is not of the ``opw`` or ``ur`` family (see
    :func:`has_closed_form`). Solutions are wrapped into the joint limits (see module docstring);
    ``valid`` marks the ones within limits whose FK reproduces the target to ``tol_m`` / ``tol_rad``
    and that are no duplicate of an earlier branch. ``use_numba=False`` runs the vectorised numpy
    reference instead of the compiled kernel. :func:`hykin.kinematics.ik.ik_closed_form` adds the
    refinement of near-singular candidates (LM).
    """
    m = poe_model(robot, structure_tol)
    if m.family is None:
        raise ClosedFormError(f"robot {robot.name!r}: no closed-form IK ({m.reason})")
    N = len(T)
    if HAVE_NUMBA and use_numba:
        ch = chain_of(robot)
        q = np.empty((N, 8, 6))
        valid = np.empty((N, 8), np.bool_)
        pe = np.empty((N, 8))
        ae = np.empty((N, 8))
        fam = 0 if m.family == "opw" else 1
        xperp = perpendicular(m.h[5] if fam == 0 else m.h[1])
        s3, s4 = float(m.h[2] @ m.h[1]), float(m.h[3] @ m.h[1])
        args = (fam, m.h, m.p, np.ascontiguousarray(m.T0[:3, :3]), m.T0[:3, 3].copy(), m.wc, xperp, s3, s4,
                np.ascontiguousarray(ch.fixed), np.ascontiguousarray(ch.prismatic, dtype=np.bool_),
                np.ascontiguousarray(robot.lower), np.ascontiguousarray(robot.upper), np.ascontiguousarray(T),
                float(tol_m), float(tol_rad), q, valid, pe, ae)
        run_chunked(_closed_form_range, args, N, min_chunk=2000)
        return IKSolutions(q=q, valid=valid, branch=np.arange(8), labels=BRANCH_LABELS, pos_err_m=pe,
                           ang_err_rad=ae, family=m.family)
    R_t, p_t = T[:, :3, :3], T[:, :3, 3]
    cand = (solve_opw if m.family == "opw" else solve_ur)(m, R_t, p_t).reshape(N, 8, 6)
    finite = np.all(np.isfinite(cand), axis=-1)
    q = wrap_to_limits(np.where(finite[..., None], cand, 0.0), robot.lower, robot.upper)
    inlim = np.all((q >= robot.lower - 1e-12) & (q <= robot.upper + 1e-12), axis=-1)
    q = np.clip(q, robot.lower, robot.upper)
    Tq = fk(robot, q.reshape(-1, 6)).reshape(N, 8, 4, 4)
    pe, ae = pose_residual(Tq, T[:, None])
    pe = np.where(finite, pe, np.inf)
    ae = np.where(finite, ae, np.inf)
    valid = finite & inlim & (pe <= tol_m) & (ae <= tol_rad)
    valid = mark_duplicates(q, valid)
    q = np.where(finite[..., None], q, np.nan)
    return IKSolutions(q=q, valid=valid, branch=np.arange(8), labels=BRANCH_LABELS, pos_err_m=pe,
                       ang_err_rad=ae, family=m.family)


# --------------------------------------------------------------------------- numba kernels
# Same algebra as solve_opw / solve_ur, one target per iteration, with the limit wrapping, FK
# check and duplicate removal fused in (the numpy path above is the reference and the fallback).

if HAVE_NUMBA:
    import numba

    from .ik_families import opw_one, ur_one
    from .ik_subproblems import mv, v3, vadd, vsub
    from .walk import fk_one

    @numba.njit(cache=True, nogil=True)
    def _finish_one(fixed, prismatic, lower, upper, T, q, ok, tol_m, tol_rad, valid, pe, ae, Tq):  # pragma: no cover
        K, n = q.shape
        for b in range(K):
            valid[b] = False
            pe[b] = np.inf
            ae[b] = np.inf
            if not ok[b]:
                for j in range(n):
                    q[b, j] = np.nan
                continue
            inlim = True
            for j in range(n):
                w = (q[b, j] + np.pi) % TWO_PI - np.pi
                klo = np.ceil((lower[j] - w) / TWO_PI - 1e-12)
                khi = np.floor((upper[j] - w) / TWO_PI + 1e-12)
                kk = min(max(np.round(-w / TWO_PI), klo), khi) if klo <= khi else 0.0
                w = w + TWO_PI * kk
                if w < lower[j] - 1e-12 or w > upper[j] + 1e-12:
                    inlim = False
                q[b, j] = min(max(w, lower[j]), upper[j])
            fk_one(fixed, prismatic, q[b], Tq)
            dx, dy, dz = Tq[0, 3] - T[0, 3], Tq[1, 3] - T[1, 3], Tq[2, 3] - T[2, 3]
            pe[b] = np.sqrt(dx * dx + dy * dy + dz * dz)
            # M = Rq Rt^T
            tr = 0.0
            for r in range(3):
                tr += Tq[r, 0] * T[r, 0] + Tq[r, 1] * T[r, 1] + Tq[r, 2] * T[r, 2]
            m21 = Tq[2, 0] * T[1, 0] + Tq[2, 1] * T[1, 1] + Tq[2, 2] * T[1, 2]
            m12 = Tq[1, 0] * T[2, 0] + Tq[1, 1] * T[2, 1] + Tq[1, 2] * T[2, 2]
            m02 = Tq[0, 0] * T[2, 0] + Tq[0, 1] * T[2, 1] + Tq[0, 2] * T[2, 2]
            m20 = Tq[2, 0] * T[0, 0] + Tq[2, 1] * T[0, 1] + Tq[2, 2] * T[0, 2]
            m10 = Tq[1, 0] * T[0, 0] + Tq[1, 1] * T[0, 1] + Tq[1, 2] * T[0, 2]
            m01 = Tq[0, 0] * T[1, 0] + Tq[0, 1] * T[1, 1] + Tq[0, 2] * T[1, 2]
            s = 0.5 * np.sqrt((m21 - m12) ** 2 + (m02 - m20) ** 2 + (m10 - m01) ** 2)
            ae[b] = np.arctan2(s, 0.5 * (tr - 1.0))
            if not (inlim and pe[b] <= tol_m and ae[b] <= tol_rad):
                continue
            dup = False
            for a in range(b):
                if valid[a]:
                    same = True
                    for j in range(n):
                        dd = (q[b, j] - q[a, j] + np.pi) % TWO_PI - np.pi
                        if abs(dd) >= 1e-7:
                            same = False
                            break
                    if same:
                        dup = True
                        break
            valid[b] = not dup

    @numba.njit(cache=True, nogil=True)
    def _closed_form_range(family, h, p, R0, P0, wc, xperp, s3, s4, fixed, prismatic, lower, upper, T,
                           tol_m, tol_rad, q, valid, pe, ae, start, stop):  # pragma: no cover - compiled
        for t in range(start, stop):
            Rd = np.empty((3, 3))
            for r in range(3):
                for cc in range(3):
                    Rd[r, cc] = T[t, r, 0] * R0[cc, 0] + T[t, r, 1] * R0[cc, 1] + T[t, r, 2] * R0[cc, 2]
            pt = (T[t, 0, 3], T[t, 1, 3], T[t, 2, 3])
            d = vsub(v3(wc), v3(P0))
            X = vadd(pt, mv(Rd, d))
            ok = np.empty(8, np.bool_)
            if family == 0:
                opw_one(h, p, Rd, X, v3(wc), v3(xperp), q[t], ok)
            else:
                ur_one(h, p, Rd, X, pt, v3(wc), v3(P0), v3(xperp), s3, s4, q[t], ok)
            Tq = np.empty((4, 4))
            _finish_one(fixed, prismatic, lower, upper, T[t], q[t], ok, tol_m, tol_rad, valid[t], pe[t], ae[t], Tq)
