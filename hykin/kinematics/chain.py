"""Kinematic chain: a robot's geometry turned into fixed transforms around unit joint motions.

Every convention (DH, MDH, URDF) reduces to the same form. Joint i contributes

    pre_i · J(q_i) · post_i,    J = Rz(q) (revolute) or Tz(q) (prismatic),

where link frame i is the frame after ``post_i`` and the *joint frame* i (z = joint axis, origin on
the axis) is the frame after ``pre_i · J(q_i)``. The full TCP pose in the world frame is

    base · pre_1 J(q_1) post_1 · pre_2 J(q_2) post_2 ··· post_n · tool
  = F_0 · J(q_1) · F_1 · J(q_2) ··· J(q_n) · F_n,

with the fused fixed transforms ``F_0 = base·pre_1``, ``F_i = post_i·pre_{i+1}``, ``F_n = post_n·tool``.

The builder is written once over an array namespace (numpy or torch), so calibration can
differentiate the chain with respect to geometric parameters (:func:`geometry_of`,
:func:`build_chain` with ``xp=torch``).
"""

from __future__ import annotations

import operator
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from .robot import Robot

__all__ = ["Chain", "build_chain", "chain_of", "geometry_of"]


@dataclass
class Chain:
    """Fixed transforms of a chain (numpy float64 or torch tensors).

    pre, post: ``(n, 4, 4)``; fixed: ``(n + 1, 4, 4)`` fused transforms; prismatic: ``(n,)`` bool.
    base, tool: ``(4, 4)``. ``n`` counts chain joints (mimic joints included).
    expand: None, or ``(index (n,) int, multiplier (n,), offset (n,))`` numpy arrays mapping the
    robot's independent joints onto the chain joints (URDF ``<mimic>``; see
    :func:`hykin.kinematics.walk.expand_joints`).
    """

    pre: Any
    post: Any
    fixed: Any
    base: Any
    tool: Any
    prismatic: np.ndarray
    expand: tuple | None = None
    n_independent: int | None = None  # the robot's independent joints (``Robot.dof``)

    @property
    def dof(self) -> int:
        """Number of chain joints (mimic joints included)."""
        return int(self.prismatic.shape[0])


def geometry_of(robot: Robot) -> dict[str, np.ndarray]:
    """The robot's differentiable geometric parameters as a dict of numpy arrays (SI).

    Keys: ``a, alpha, d, theta, beta`` ``(n,)``; ``origin`` ``(n, 4, 4)`` (URDF joint origins; identity
    for DH/MDH); ``base``, ``tool`` ``(4, 4)``. Calibration perturbs these and calls
    :func:`build_chain`.
    """
    from ..geometry import se3

    if robot.convention == "urdf":
        origin = se3.xyzrpy_to_transform(robot.origin_xyz_m, robot.origin_rpy_rad)
    else:
        origin = np.tile(np.eye(4), (robot.n_chain, 1, 1))
    return {
        "a": robot.a_m.copy(),
        "alpha": robot.alpha_rad.copy(),
        "d": robot.d_m.copy(),
        "theta": robot.theta_rad.copy(),
        "beta": robot.beta_rad.copy(),
        "origin": origin,
        "base": robot.base.copy(),
        "tool": robot.tool.copy(),
    }


def _elem(xp, kind: str, v):
    """Batch of elementary transforms ``(n, 4, 4)`` from values ``(n,)`` in namespace ``xp``."""
    one, zero = xp.ones_like(v), xp.zeros_like(v)
    if kind in ("rx", "ry", "rz"):
        c, s = xp.cos(v), xp.sin(v)
        if kind == "rx":
            rows = [one, zero, zero, zero, zero, c, -s, zero, zero, s, c, zero]
        elif kind == "ry":
            rows = [c, zero, s, zero, zero, one, zero, zero, -s, zero, c, zero]
        else:
            rows = [c, -s, zero, zero, s, c, zero, zero, zero, zero, one, zero]
    else:
        x = v if kind == "tx" else zero
        z = v if kind == "tz" else zero
        rows = [one, zero, zero, x, zero, one, zero, zero, zero, zero, one, z]
    rows += [zero, zero, zero, one]
    return xp.stack(rows, -1).reshape(tuple(v.shape) + (4, 4))


def _align_z(axis: np.ndarray) -> np.ndarray:
    """Rotations ``(n, 4, 4)`` taking +z onto each unit ``axis`` (n, 3) (minimal rotation)."""
    from ..geometry import se3

    n = axis.shape[0]
    z = np.array([0.0, 0.0, 1.0])
    out = np.tile(np.eye(4), (n, 1, 1))
    for i, a in enumerate(axis):
        v = np.cross(z, a)
        s, c = np.linalg.norm(v), float(z @ a)
        if s < 1e-12:
            R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
        else:
            R = se3.rotvec_to_matrix(v / s * np.arctan2(s, c))
        out[i, :3, :3] = R
    return out


def build_chain(robot: Robot, geom: dict | None = None, xp=np) -> Chain:
    """Build the :class:`Chain` of ``robot`` from its geometry (or the overrides in ``geom``).

    ``xp`` is ``numpy`` or ``torch``; with torch, ``geom`` values must be float64 tensors and the
    result is differentiable with respect to them.
    """
    g = geometry_of(robot) if geom is None else geom
    if xp is np:
        g = {k: np.asarray(v, dtype=np.float64) for k, v in g.items()}
    prism = np.array([t == "prismatic" for t in robot.joint_type])
    E = lambda kind, v: _elem(xp, kind, v)
    n = robot.n_chain
    if robot.convention == "dh":
        # Rz(θ) [Tz(d) if prismatic] · J · [Tz(d) if revolute] Tx(a) Rx(α) Ry(β)
        d_pre = g["d"] * _as(xp, prism, g["d"])
        d_post = g["d"] - d_pre
        pre = E("rz", g["theta"]) @ E("tz", d_pre)
        post = E("tz", d_post) @ E("tx", g["a"]) @ E("rx", g["alpha"]) @ E("ry", g["beta"])
    elif robot.convention == "mdh":
        d_pre = g["d"] * _as(xp, prism, g["d"])
        d_post = g["d"] - d_pre
        pre = E("rx", g["alpha"]) @ E("tx", g["a"]) @ E("ry", g["beta"]) @ E("rz", g["theta"]) @ E("tz", d_pre)
        post = E("tz", d_post)
    else:  # urdf: origin · Align · J · Alignᵀ  (J about/along z)
        A = _align_z(robot.axis)
        At = np.swapaxes(A, -1, -2).copy()
        if xp is not np:
            A = xp.as_tensor(A, dtype=g["origin"].dtype)
            At = xp.as_tensor(At, dtype=g["origin"].dtype)
        pre = g["origin"] @ A
        post = At
    base, tool = g["base"], g["tool"]
    cat = np.concatenate if xp is np else xp.cat
    fixed = cat([(base @ pre[0])[None], post[:-1] @ pre[1:], (post[n - 1] @ tool)[None]], 0)
    return Chain(pre=pre, post=post, fixed=fixed, base=base, tool=tool, prismatic=prism, expand=robot.expansion(),
                 n_independent=robot.dof)


def _as(xp, mask: np.ndarray, like):
    if xp is np:
        return mask.astype(np.float64)
    return xp.as_tensor(mask, dtype=like.dtype, device=like.device)


# Fields whose *objects* key the chain cache (see :func:`chain_of`).
_GEOMETRY_FIELDS = (
    "convention", "joint_type", "a_m", "alpha_rad", "d_m", "theta_rad", "beta_rad", "origin_xyz_m",
    "origin_rpy_rad", "axis", "base", "tool", "mimic",
)
_get_geometry = operator.itemgetter(*_GEOMETRY_FIELDS)  # applied to robot.__dict__ (C-level lookups)


def chain_of(robot: Robot) -> Chain:
    """Cached numpy :class:`Chain` of ``robot`` (rebuilt when the robot's geometry changes).

    Cache rule: the cache is keyed on the *identity* of the robot's geometry fields (``convention``,
    ``joint_type``, ``a_m``, ``alpha_rad``, ``d_m``, ``theta_rad``, ``beta_rad``, ``origin_xyz_m``,
    ``origin_rpy_rad``, ``axis``, ``base``, ``tool``, ``mimic``), which makes a cache hit cost well under a
    microsecond. Assigning a new array to a field (``robot.d_m = d2``) or ``robot.copy(...)`` gives a new
    chain. So that a stale chain can never be returned, the cached robot's geometry arrays are made
    read-only: in-place edits (``robot.d_m[0] += 1e-3``) raise ``ValueError`` instead of being missed;
    assign a new array or use ``robot.copy(d_m=...)`` to change geometry.
    """
    fields = _get_geometry(robot.__dict__)
    cached = _CACHE.get(id(robot))
    if cached is not None and cached[0]() is robot:
        # ``tuple ==`` checks identity first, so identical fields cost a pointer compare each. A field
        # replaced by another array raises (ambiguous truth value) -> rebuild; only 1-element arrays
        # (1-DOF robots) could compare equal without being identical, so those use ``is`` throughout.
        try:
            hit = all(map(operator.is_, fields, cached[1])) if cached[3] else fields == cached[1]
        except ValueError:
            hit = False
        if hit:
            return cached[2]
    ch = build_chain(robot)
    for arr in fields[2:]:
        if isinstance(arr, np.ndarray):
            arr.flags.writeable = False
    key = id(robot)

    def _drop(ref, key=key):  # robot garbage-collected: forget its chain
        entry = _CACHE.get(key)
        if entry is not None and entry[0] is ref:
            del _CACHE[key]

    strict = any(isinstance(f, np.ndarray) and f.size == 1 for f in fields)
    _CACHE[key] = (weakref.ref(robot, _drop), fields, ch, strict)
    return ch


# id(robot) -> (weakref to robot, geometry field objects, Chain, strict identity check). Kept outside the robot so that
# copy.deepcopy / pickle of a robot never carry a chain keyed on the original's arrays.
_CACHE: dict[int, tuple] = {}
