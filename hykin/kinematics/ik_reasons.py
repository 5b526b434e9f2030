"""Why an IK target was not solved, in one of four words a user can act on.

Every IK row path (classical, hybrid, position only, all branches, nearest) writes no joint values for
an unsolved target, and a ``reason`` that starts with one of :data:`CATEGORIES`:

* ``out of reach`` — no configuration of the robot reaches the pose, whatever the joint limits;
* ``joint limits`` — the pose is reachable only with joints outside their limits;
* ``singular`` — the solver stalled at a configuration whose Jacobian is (nearly) rank deficient;
* ``not converged`` — none of the above could be shown: the solver did not get there.
"""

from __future__ import annotations

import numpy as np

from .robot import Robot

__all__ = ["CATEGORIES", "categorise", "failure_reasons", "is_singular", "open_revolute_limits"]

CATEGORIES = ("out of reach", "joint limits", "singular", "not converged")
# Smallest / largest singular value of the scaled Jacobian below which a configuration counts as
# singular (the same relative threshold the branch-count report uses).
SING_REL = 0.02


def is_singular(robot: Robot, q, position_only: bool = False, rel: float = SING_REL) -> np.ndarray:
    """``(N,)`` bool: the TCP Jacobian at ``q`` ``(N, dof)`` (finite rows) is nearly rank deficient
    (translation rows scaled by the robot's reach so metres and radians weigh alike)."""
    from .fk import jacobian
    from .robot import robot_reach_m

    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    out = np.zeros(len(q), dtype=bool)
    ok = np.isfinite(q).all(axis=1)
    if not ok.any():
        return out
    J = jacobian(robot, q[ok]).copy()
    J[:, :3] /= max(robot_reach_m(robot), 1e-9)
    if position_only:
        J = J[:, :3]
    s = np.linalg.svd(J, compute_uv=False)
    k = min(J.shape[1], J.shape[2])
    out[ok] = s[:, k - 1] < rel * s[:, 0]
    return out


def open_revolute_limits(robot: Robot) -> Robot:
    """The robot with revolute limits opened to ±2π (prismatic strokes kept): every configuration
    a revolute joint can take has a representation there."""
    rev = robot.revolute
    return robot.copy(lower=np.where(rev, -2 * np.pi, robot.lower), upper=np.where(rev, 2 * np.pi, robot.upper))


def failure_reasons(robot: Robot, T_target, position_only: bool = False, q_best=None,
                    classical_failed=None) -> np.ndarray:
    """Categorised reasons ``(N,)`` (str) for unsolved targets ``(N, 4, 4)`` (m; positions ``(N, 3)``
    for position-only). ``q_best`` ``(N, dof)``: the solver's best attempts (NaN rows when none), for
    the singularity test. ``classical_failed`` ``(N,)`` bool: classical IK within the limits found no
    solution (default: all) — only those are tested for "joint limits" (classical IK with the revolute
    limits opened to ±2π); the others failed later (hybrid refinement) and are out of reach, singular
    or not converged."""
    from .ik import ik
    from .ik_closed_form import has_closed_form
    from .robot import robot_reach_m

    T = np.asarray(T_target, dtype=np.float64)
    if T.ndim == 2:  # positions only
        P = T
        T = np.tile(np.eye(4), (len(P), 1, 1))
        T[:, :3, 3] = P
        position_only = True
    N = len(T)
    out = np.full(N, "", dtype=object)
    if N == 0:
        return out.astype(str)
    cf = np.ones(N, dtype=bool) if classical_failed is None else np.asarray(classical_failed, dtype=bool)
    far = np.linalg.norm(T[:, :3, 3] - robot.base[:3, 3], axis=1) > robot_reach_m(robot)
    lim = np.zeros(N, dtype=bool)
    test = cf & ~far
    if test.any():
        wide = ik(open_revolute_limits(robot), T[test], all_branches=True, position_only=position_only)
        lim[test] = wide.success.any(axis=1)
    sing = np.zeros(N, dtype=bool) if q_best is None else is_singular(robot, q_best, position_only)
    closed = bool(has_closed_form(robot)) and not position_only  # a closed form finds every solution
    out[:] = "not converged: the solver did not reach the target"
    out[cf] = ("out of reach: no joint configuration of the robot reaches this pose" if closed
               else "not converged: numerical IK found no solution (the pose may be out of reach)")
    if robot.dof < 6 and not position_only and (cf & ~far & ~lim).any():  # an arm that cannot take every orientation
        t = np.flatnonzero(cf & ~far & ~lim)
        pos_ok = ik(robot, T[t], all_branches=True, position_only=True).success.any(axis=1)
        out[t[pos_ok]] = (f"not converged: the arm has {robot.dof} joints and takes no orientation within 1e-4 deg of this "
                          "one at this position (the position alone is reachable: solve positions only, e.g. --position-only)")
    out[~lim & sing] = "singular: the solver stalled at a singular configuration"
    out[lim] = "joint limits: the pose is reachable only with joints outside their limits"
    out[far] = f"out of reach: farther from the base than the robot reaches ({robot_reach_m(robot):.3g} m)"
    return out.astype(str)


def categorise(reason: str, singular: bool = False) -> str:
    """A solver's free-text failure reason prefixed with its category (:data:`CATEGORIES`)."""
    r = reason.lower()
    if any(r.startswith(c) for c in CATEGORIES):
        return reason
    if "no classical solution" in r or ("unreachable" in r and "did not converge" not in r):
        cat = "out of reach"
    elif "joint limit" in r:
        cat = "joint limits"
    elif singular:
        cat = "singular"
    else:
        cat = "not converged"
    return f"{cat}: {reason}" if reason else cat
