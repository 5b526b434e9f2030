"""Sampling plans: where in joint space to measure (DESIGN.md §1.4 "Data collection").

Every plan returns an ``(N, n)`` float64 array of joints (rad; m for prismatic joints) inside the
robot's limits:

* :func:`uniform` — low-discrepancy (scrambled Sobol, or Halton) points scaled to the joint ranges: the
  paper's pseudo-uniform 500k set.
* :func:`random` — independent uniform draws.
* :func:`zigzag` — a continuous training trajectory: each joint sweeps its range back and forth
  (triangle wave) at its own, mutually incommensurate rate; sampled at ``N`` equal time steps.
* :func:`restricted` — uniform/random in sub-ranges (a fraction of each range around its middle, or
  explicit ranges): the "reduced range" of real measurement campaigns.
* :func:`iso_cube` — ISO 9283 pose test: a cube in the workspace, poses P1..P5 on its diagonal plane
  at constant orientation, repeated for ``cycles``; joints by numerical IK. Returns joints *and*
  pose labels (:class:`IsoCubePlan`).

:func:`sample` dispatches by plan name.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from ..kinematics.fk import fk, jacobian
from ..kinematics.robot import Robot

__all__ = [
    "PLANS",
    "IsoCubePlan",
    "PlanError",
    "iso_cube",
    "random",
    "restricted",
    "sample",
    "uniform",
    "zigzag",
]


class PlanError(ValueError):
    """Bad sampling-plan request (unknown plan, bad ranges, unreachable ISO cube)."""


def _rng(rng) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def _check_n(n) -> int:
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise PlanError(f"number of samples must be a positive integer, got {n!r}")
    return int(n)


def _scale(u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.clip(lo + u * (hi - lo), lo, hi)


def uniform(robot: Robot, n: int, rng=None, *, method: str = "sobol", lower=None, upper=None) -> np.ndarray:
    """``(n, dof)`` low-discrepancy joints within limits (or within ``lower``/``upper``).

    ``method``: ``"sobol"`` (scrambled, any ``n``; a power of two is best balanced) or ``"halton"``.
    ``rng`` seeds the scrambling, so the set is reproducible.
    """
    n = _check_n(n)
    lo = robot.lower if lower is None else np.asarray(lower, dtype=np.float64)
    hi = robot.upper if upper is None else np.asarray(upper, dtype=np.float64)
    rng = _rng(rng)
    if method == "sobol":
        eng = qmc.Sobol(d=robot.dof, scramble=True, seed=rng)
        m = int(np.ceil(np.log2(n)))
        u = eng.random_base2(m)[:n]
    elif method == "halton":
        u = qmc.Halton(d=robot.dof, scramble=True, seed=rng).random(n)
    else:
        raise PlanError(f"uniform: method must be 'sobol' or 'halton', got {method!r}")
    return _scale(u, lo, hi)


def random(robot: Robot, n: int, rng=None, *, lower=None, upper=None) -> np.ndarray:
    """``(n, dof)`` independent uniform joints within limits (or ``lower``/``upper``)."""
    n = _check_n(n)
    lo = robot.lower if lower is None else np.asarray(lower, dtype=np.float64)
    hi = robot.upper if upper is None else np.asarray(upper, dtype=np.float64)
    return _scale(_rng(rng).random((n, robot.dof)), lo, hi)


# Golden-ratio-like, mutually incommensurate sweep-rate multipliers (square roots of primes).
_RATES = np.sqrt(np.array([2.0, 3.0, 5.0, 7.0, 11.0, 13.0, 17.0, 19.0, 23.0, 29.0, 31.0, 37.0]))


def zigzag(
    robot: Robot, n: int, rng=None, *, sweeps: float | None = None, lower=None, upper=None, margin: float = 0.0
) -> np.ndarray:
    """A continuous trajectory sweeping every joint back and forth, sampled at ``n`` equal steps.

    Joint j follows a triangle wave between its limits (shrunk by ``margin``, a fraction of the
    range) with ``sweeps * r_j`` full back-and-forth cycles over the trajectory (``r_j`` = sqrt of the
    j-th prime / sqrt 2, so no two joints lock in phase) and a random start phase from ``rng``.
    ``sweeps`` defaults to ``max(1, n / 2000)``: consecutive samples move at most
    ``2 * sweeps * r_j / n`` of a joint's range. Returns ``(n, dof)``.
    """
    n = _check_n(n)
    dof = robot.dof
    if dof > _RATES.size:
        raise PlanError(f"zigzag supports up to {_RATES.size} joints")
    lo = robot.lower if lower is None else np.asarray(lower, dtype=np.float64)
    hi = robot.upper if upper is None else np.asarray(upper, dtype=np.float64)
    span = hi - lo
    lo, hi = lo + margin * span, hi - margin * span
    sweeps = max(1.0, n / 2000.0) if sweeps is None else float(sweeps)
    rates = sweeps * _RATES[:dof] / _RATES[0]
    phase = _rng(rng).random(dof)
    t = np.arange(n, dtype=np.float64)[:, None] / max(n - 1, 1)
    x = np.mod(t * rates[None] + phase[None], 1.0)
    tri = 1.0 - np.abs(2.0 * x - 1.0)  # 0 -> 1 -> 0 per cycle, continuous
    return _scale(tri, lo, hi)


def restricted(
    robot: Robot,
    n: int,
    rng=None,
    *,
    fraction: float | np.ndarray = 0.5,
    ranges=None,
    center=None,
    method: str = "uniform",
) -> np.ndarray:
    """Joints in sub-ranges: ``(n, dof)``.

    ``ranges``: explicit ``(dof, 2)`` ``[lower, upper]`` (must lie within the limits); otherwise each
    joint spans ``fraction`` (scalar or per joint, in (0, 1]) of its range around ``center`` (default
    the middle of the range; the window is shifted to stay inside the limits). ``method``:
    ``"uniform"`` (Sobol), ``"random"`` or ``"zigzag"``.
    """
    if ranges is not None:
        r = np.asarray(ranges, dtype=np.float64)
        if r.shape != (robot.dof, 2) or np.any(r[:, 0] > r[:, 1]):
            raise PlanError(f"restricted: ranges must be ({robot.dof}, 2) with lower <= upper")
        if np.any(r[:, 0] < robot.lower - 1e-12) or np.any(r[:, 1] > robot.upper + 1e-12):
            j = int(np.argmax((r[:, 0] < robot.lower - 1e-12) | (r[:, 1] > robot.upper + 1e-12)))
            raise PlanError(f"restricted: range of joint {j + 1} {r[j]} exceeds the limits "
                            f"[{robot.lower[j]:.6g}, {robot.upper[j]:.6g}]")
        lo, hi = r[:, 0], r[:, 1]
    else:
        f = np.broadcast_to(np.asarray(fraction, dtype=np.float64), (robot.dof,))
        if np.any(~(f > 0)) or np.any(f > 1):
            raise PlanError(f"restricted: fraction must be in (0, 1], got {fraction!r}")
        span = robot.upper - robot.lower
        c = 0.5 * (robot.lower + robot.upper) if center is None else np.asarray(center, dtype=np.float64)
        half = 0.5 * f * span
        lo = np.clip(c - half, robot.lower, robot.upper - 2 * half)
        hi = lo + 2 * half
    fn = {"uniform": uniform, "random": random, "zigzag": zigzag}.get(method)
    if fn is None:
        raise PlanError(f"restricted: method must be uniform, random or zigzag, got {method!r}")
    return fn(robot, n, rng, lower=lo, upper=hi)


# --------------------------------------------------------------------------- ISO 9283 cube


@dataclass
class IsoCubePlan:
    """ISO 9283 pose-test plan.

    q: ``(cycles * 5, dof)`` joints, cycles of P1..P5. labels: ``(cycles * 5,)`` int 1..5 (P1..P5).
    points_m: ``(5, 3)`` commanded TCP positions (world frame). rotation: ``(3, 3)`` commanded
    orientation (constant). center_m: ``(3,)``; side_m: cube edge; normal: unit normal of the
    diagonal test plane.
    """

    q: np.ndarray
    labels: np.ndarray
    points_m: np.ndarray
    rotation: np.ndarray
    center_m: np.ndarray
    side_m: float
    normal: np.ndarray


def _reach(robot: Robot) -> float:
    return float(np.sum(np.abs(robot.a_m)) + np.sum(np.abs(robot.d_m)) + np.linalg.norm(robot.tool[:3, 3]))


def _shoulder_and_reach(robot: Robot) -> tuple[np.ndarray, float]:
    """Joint-2 axis origin at zero joints (robot base frame) and the 95th percentile of the TCP's
    distance from it over random joints (a robust working reach)."""
    from ..kinematics.fk import fk_frames

    q0 = np.clip(np.zeros((1, robot.dof)), robot.lower, robot.upper)
    inv_base = np.linalg.inv(robot.base)
    j = min(1, robot.dof - 1)
    shoulder = (inv_base @ fk_frames(robot, q0).joint[0, j])[:3, 3]
    q = robot.random_joints(2000, np.random.default_rng(12345))
    p = (inv_base[None] @ fk(robot, q))[:, :3, 3]
    return shoulder, float(np.percentile(np.linalg.norm(p - shoulder, axis=1), 95))


def _pose_ik(robot: Robot, T_target: np.ndarray, seeds: np.ndarray, tol_m: float = 1e-9, ref=None):
    """Numerical IK (damped least squares on fk, scipy) from several seeds; best solution or None."""
    from scipy.optimize import least_squares

    from ..geometry.se3 import rotation_difference_rotvec

    lo, hi = robot.lower, robot.upper
    L = max(_reach(robot), 1e-3)  # scale angles to metres so both residuals weigh alike

    def res(q):
        T = fk(robot, q)
        return np.concatenate([T[:3, 3] - T_target[:3, 3], L * rotation_difference_rotvec(T[:3, :3], T_target[:3, :3])])

    def jac(q):
        J = jacobian(robot, q)
        J = J.copy()
        J[3:] *= L
        return J

    best = None
    for s in seeds:
        s = np.clip(s, lo + 1e-9, hi - 1e-9)
        sol = least_squares(res, s, jac=jac, bounds=(lo, hi), method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        err = np.linalg.norm(sol.fun)
        if best is None or err < best[1]:
            best = (_wrap_towards(robot, sol.x, ref), err)
        if err < tol_m:
            break
    return best


def _wrap_towards(robot: Robot, q: np.ndarray, ref=None) -> np.ndarray:
    """Shift revolute joints by multiples of 2π towards ``ref`` (default: mid-range); same pose."""
    q = q.copy()
    mid = 0.5 * (robot.lower + robot.upper) if ref is None else ref
    for i, t in enumerate(robot.independent_joint_type):
        if t == "revolute":
            k = np.round((q[i] - mid[i]) / (2 * np.pi))
            cand = q[i] - k * 2 * np.pi
            if robot.lower[i] <= cand <= robot.upper[i]:
                q[i] = cand
    return q


def iso_cube(
    robot: Robot,
    cycles: int = 30,
    rng=None,
    *,
    center_m=None,
    side_m: float | None = None,
    rotation=None,
    n_seeds: int = 40,
) -> IsoCubePlan:
    """ISO 9283 cube: P1 at the centre, P2..P5 on the diagonals of the diagonal plane, 10 % of the
    diagonal length in from the corners; constant orientation; ``cycles`` repetitions of P1..P5.

    The diagonal plane contains two opposite vertical cube edges: it is spanned by ``(1, 1, 0)/√2``
    and ``z`` (world frame) through the centre, normal ``(1, -1, 0)/√2``; its corners are cube corners,
    its diagonals are cube space diagonals. Defaults: centre half the working reach R (95th
    percentile of the TCP distance from the joint-2 axis origin) in front of that origin along
    base x, edge 0.25 R, tool z pointing down. Joints come from numerical IK
    (scipy least_squares, random seeds from ``rng``), P2..P5 seeded from P1 to stay on one branch.
    Raises :class:`PlanError` when a pose is not reachable to 1e-6 m.
    """
    cycles = _check_n(cycles)
    rng = _rng(rng)
    base_R, base_p = robot.base[:3, :3], robot.base[:3, 3]
    shoulder, reach = _shoulder_and_reach(robot)
    if center_m is None:
        center_m = base_p + base_R @ (shoulder + np.array([0.5 * reach, 0.0, 0.0]))
    c = np.asarray(center_m, dtype=np.float64).reshape(3)
    side = 0.25 * reach if side_m is None else float(side_m)
    if not side > 0:
        raise PlanError(f"iso_cube: side_m must be > 0, got {side_m!r}")
    R = base_R @ np.diag([1.0, -1.0, -1.0]) if rotation is None else np.asarray(rotation, dtype=np.float64)
    hs = side / 2
    u = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    w = np.array([0.0, 0.0, 1.0])
    normal = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    corners = np.array([c + sx * hs * np.sqrt(2.0) * u + sz * hs * w for sx, sz in ((1, 1), (-1, 1), (-1, -1), (1, -1))])
    pts = np.vstack([c, c + 0.8 * (corners - c)])  # 10 % of the diagonal (= 2 * 0.1 * half) from the corners
    q_pts = np.empty((5, robot.dof))
    seeds = robot.random_joints(n_seeds, rng, margin=0.05)
    for k, p in enumerate(pts):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, p
        s = seeds if k == 0 else np.vstack([q_pts[0], seeds[:5]])
        best = _pose_ik(robot, T, s, ref=None if k == 0 else q_pts[0])
        if best is None or best[1] > 1e-6:
            raise PlanError(
                f"iso_cube: pose P{k + 1} at {np.round(p, 4).tolist()} m is not reachable "
                f"(residual {best[1] if best else float('nan'):.3g}); choose another center_m/side_m"
            )
        q_pts[k] = best[0]
    q = np.tile(q_pts, (cycles, 1))
    labels = np.tile(np.arange(1, 6), cycles)
    return IsoCubePlan(q=q, labels=labels, points_m=pts, rotation=R, center_m=c, side_m=side, normal=normal)


# --------------------------------------------------------------------------- dispatcher

PLANS = ("uniform", "random", "zigzag", "iso_cube", "restricted")


def sample(plan: str, robot: Robot, n: int, rng=None, **kw) -> np.ndarray:
    """Joints ``(n, dof)`` from the named plan (``uniform``, ``random``, ``zigzag``, ``iso_cube``,
    ``restricted``; ``-`` and ``_`` are interchangeable). Extra keywords go to the plan function.
    For ``iso_cube``, ``n`` poses are the first ``n`` of ``ceil(n / 5)`` cycles (labels: use
    :func:`iso_cube`).
    """
    name = str(plan).replace("-", "_").lower()
    n = _check_n(n)
    if name == "uniform":
        return uniform(robot, n, rng, **kw)
    if name == "random":
        return random(robot, n, rng, **kw)
    if name == "zigzag":
        return zigzag(robot, n, rng, **kw)
    if name == "restricted":
        return restricted(robot, n, rng, **kw)
    if name == "iso_cube":
        return iso_cube(robot, cycles=-(-n // 5), rng=rng, **kw).q[:n]
    raise PlanError(f"unknown sampling plan {plan!r}; choose one of {', '.join(PLANS)}")
