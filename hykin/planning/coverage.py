"""Space-filling in the joint space the networks see.

The residual networks take the joints min-max normalised over the trained region, revolute joints
that can turn a full circle wrapped onto it (:class:`hykin.hybrid.HybridModel`, ``periodic="wrap"``).
Coverage is measured in the same coordinates: :func:`embed` maps joints to a Euclidean space where

* a joint whose region spans less than a full turn becomes ``u = (q - lo) / (hi - lo)`` in [0, 1];
* a revolute joint whose region spans a full turn (≥ 2π) becomes the point
  ``(cos q, sin q) / (2π)`` on a circle of circumference 1: distances along the circle are in
  units of a turn, so q and q + 2π (the same pose, the same network input) coincide.

:func:`farthest_point` is greedy maximin selection (Gonzalez's 2-approximation of the
k-centre problem): each new point is the candidate farthest from every point chosen so far.
:func:`fill_distance` is the covering radius of a set over a reference sample (smaller is better).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..kinematics.robot import Robot

__all__ = ["embed", "farthest_point", "fill_distance", "min_spacing"]

_TWO_PI = 2.0 * np.pi


def embed(robot: Robot, q, lower, upper) -> np.ndarray:
    """``(N, d)`` coverage coordinates of joints ``q`` ``(N, dof)`` for the region ``[lower, upper]``
    (module docstring; ``d = dof +`` the number of wrapped joints)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    cols = []
    for j in range(robot.dof):
        if robot.joint_type[j] == "revolute" and hi[j] - lo[j] >= _TWO_PI - 1e-9:
            cols += [np.cos(q[:, j]) / _TWO_PI, np.sin(q[:, j]) / _TWO_PI]
        else:
            cols.append((q[:, j] - lo[j]) / max(hi[j] - lo[j], 1e-12))
    return np.stack(cols, 1)


def farthest_point(X: np.ndarray, k: int, chosen=None, exclude=None) -> np.ndarray:
    """Indices of ``k`` rows of ``X`` ``(M, d)`` picked greedily by maximin distance.

    ``chosen``: indices already in the design (distances start from them; not returned). Without
    them the first pick is the row nearest the centroid. ``exclude``: bool mask of rows not to pick.
    """
    X = np.asarray(X, dtype=np.float64)
    M = len(X)
    dmin = np.full(M, np.inf)
    if exclude is not None:
        dmin[np.asarray(exclude, dtype=bool)] = -np.inf
    if chosen is not None and len(chosen):
        tree = cKDTree(X[np.asarray(chosen)])
        d, _ = tree.query(X, k=1)
        dmin = np.minimum(dmin, d)
        dmin[np.asarray(chosen)] = -np.inf
    out = np.empty(k, dtype=np.int64)
    for i in range(k):
        if i == 0 and (chosen is None or not len(chosen)):
            c = X.mean(0)
            s = np.einsum("ij,ij->i", X - c, X - c)
            s[dmin == -np.inf] = np.inf
            j = int(np.argmin(s))
        else:
            j = int(np.argmax(dmin))
        if not dmin[j] > -np.inf:
            raise ValueError(f"farthest_point: only {i} candidates available for {k} picks")
        out[i] = j
        diff = X - X[j]
        dmin = np.minimum(dmin, np.sqrt(np.einsum("ij,ij->i", diff, diff)))
        dmin[j] = -np.inf
    return out


def fill_distance(X_design: np.ndarray, X_ref: np.ndarray) -> tuple[float, float]:
    """(max, mean) distance from the reference points ``X_ref`` to their nearest design point."""
    d, _ = cKDTree(X_design).query(X_ref, k=1)
    return float(d.max()), float(d.mean())


def min_spacing(X_design: np.ndarray) -> float:
    """Smallest distance between two design points (maximin value)."""
    if len(X_design) < 2:
        return float("inf")
    d, _ = cKDTree(X_design).query(X_design, k=2)
    return float(d[:, 1].min())
