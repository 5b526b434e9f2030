"""The robot's own body as capsules: floor, keep-out boxes and self-collision for planned poses.

A robot file holds no link geometry, so the body is approximated by capsules (segments with a
radius) along the kinematic chain, in the world frame of :func:`hykin.kinematics.fk.fk` (``base``
applied):

* body 0, the **base column**: along joint 1's axis, from the base origin's foot on that axis to the
  foot of joint 2's origin (fixed: it does not move with any joint);
* body k (k = 1 … n), the **link moved by joint k**: an L through joint k's origin, the foot of the
  next joint's origin on axis k, and the next joint's origin (the flange for the last joint). For DH
  and MDH chains this is the ``d`` then ``a`` offset of the link;
* body n+1, the **tool**: flange origin to TCP.

Radii (m): given per body (``radii_m``, n + 2 values: base column, links 1…n, tool), or estimated
from the robot's reach ``R`` (:func:`hykin.kinematics.robot.robot_reach_m`): base column
``clip(0.08 R, 0.03, 0.25)``, link k ``clip(0.06 R (1 - k / 2n), 0.02, 0.2)`` (links thin toward
the wrist), tool 0.02. The estimate is deliberately coarse; give measured radii for a tight cell.

Which checks apply is decided from the structure, the way MoveIt's set-up assistant builds its
collision matrix: two bodies are never tested against each other when they are adjacent in the
chain or when they touch in at least 95 % of ``n_structure`` configurations spread over the joint
ranges (they overlap by construction, e.g. a wrist's short links); a body is not tested against the
floor when it touches the floor in at least 95 % of them (the base column and the first link of a
floor-mounted robot stand on it). Everything else must keep clear in every checked configuration.

Keep-out boxes are tested with the body sampled every half radius along each segment and the box
grown by the radius (conservative by at most a few percent of the radius). Points (the tracker) are
tested by their distance to each capsule's segments (:func:`point_clearance`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics.fk import fk_frames
from ..kinematics.robot import Robot, robot_reach_m

__all__ = ["BodyModel", "body_clear", "body_model", "body_name", "body_segments", "point_clearance", "segment_distance"]

_TOOL_RADIUS_M = 0.02
#: a pair (or a body and the floor) touching in at least this share of spread configurations overlaps by
#: construction and is not tested
_STRUCTURAL = 0.95


@dataclass
class BodyModel:
    """Capsule model of a robot (module docstring).

    radii_m: ``(B,)`` radius per body (B = chain joints + 2; a mimic joint moves a body of its own). pairs: ``(P, 2)`` body pairs tested for
    self-collision. floor_bodies: ``(B,)`` bool, bodies tested against the floor."""

    radii_m: np.ndarray
    pairs: np.ndarray
    floor_bodies: np.ndarray


def _foot(o: np.ndarray, z: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Foot of point ``p`` on the line through ``o`` along unit ``z`` (batched ``(..., 3)``)."""
    return o + np.sum((p - o) * z, axis=-1, keepdims=True) * z


def body_segments(robot: Robot, q) -> tuple[np.ndarray, np.ndarray]:
    """Segments ``(N, S, 2, 3)`` (m, world frame) and the body of each segment ``(S,)`` (module docstring)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    fr = fk_frames(robot, q)
    o = fr.joint[:, :, :3, 3]  # (N, n, 3) joint origins, on the axes
    z = fr.joint[:, :, :3, 2]
    n = robot.n_chain
    nxt = np.concatenate([o[:, 1:], fr.link[:, -1:, :3, 3]], axis=1)  # next joint origin / flange
    foot = _foot(o, z, nxt)
    base_o = np.broadcast_to(robot.base[:3, 3], o[:, 0].shape)
    col = np.stack([_foot(o[:, 0], z[:, 0], base_o), _foot(o[:, 0], z[:, 0], nxt[:, 0])], axis=1)  # (N, 2, 3)
    links = np.stack([np.stack([o, foot], axis=2), np.stack([foot, nxt], axis=2)], axis=2)  # (N, n, 2, 2, 3)
    tool = np.stack([fr.link[:, -1, :3, 3], fr.tcp[:, :3, 3]], axis=1)
    seg = np.concatenate([col[:, None], links.reshape(len(q), 2 * n, 2, 3), tool[:, None]], axis=1)
    body = np.concatenate([[0], np.repeat(np.arange(1, n + 1), 2), [n + 1]])
    return seg, body


def segment_distance(a0, a1, b0, b1) -> np.ndarray:
    """Distance between segments ``a0-a1`` and ``b0-b1`` (``(..., 3)`` each, broadcast), the closest
    points by clamped parameters (Ericson, Real-Time Collision Detection §5.1.9); degenerate
    segments are points."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    eps = 1e-18
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > eps * np.maximum(a * e, eps), np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        s = np.where(e > eps, s, np.clip(-c / np.where(a > eps, a, 1.0), 0.0, 1.0))  # b a point
        s = np.where(a > eps, s, 0.0)  # a a point
        t = np.where(e > eps, (b * s + f) / e, 0.0)
        # t outside [0, 1]: clamp it and recompute s for that end of segment b
        t_c = np.clip(t, 0.0, 1.0)
        s = np.where((t < 0.0) & (a > eps) & (e > eps), np.clip(-c / np.where(a > eps, a, 1.0), 0.0, 1.0), s)
        s = np.where((t > 1.0) & (a > eps) & (e > eps), np.clip((b - c) / np.where(a > eps, a, 1.0), 0.0, 1.0), s)
    pa = a0 + s[..., None] * d1
    pb = b0 + t_c[..., None] * d2
    return np.linalg.norm(pa - pb, axis=-1)


def _default_radii(robot: Robot) -> np.ndarray:
    R = robot_reach_m(robot)
    n = robot.n_chain
    k = np.arange(1, n + 1)
    links = np.clip(0.06 * R * (1.0 - k / (2.0 * n)), 0.02, 0.2)
    return np.concatenate([[np.clip(0.08 * R, 0.03, 0.25)], links, [_TOOL_RADIUS_M]])


def _pair_distances(seg: np.ndarray, body: np.ndarray, radii: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """``(N, P)`` clearance (m; < 0: touching) of each body pair: min over their segments (one
    vectorised distance over every segment combination, reduced per pair)."""
    if len(pairs) == 0:
        return np.zeros((seg.shape[0], 0))
    sa, sb, starts = [], [], []
    for i, j in pairs:
        si, sj = np.flatnonzero(body == i), np.flatnonzero(body == j)
        starts.append(len(sa))
        sa += list(np.repeat(si, len(sj)))
        sb += list(np.tile(sj, len(si)))
    sa, sb = np.array(sa), np.array(sb)
    d = segment_distance(seg[:, sa, 0], seg[:, sa, 1], seg[:, sb, 0], seg[:, sb, 1])  # (N, C)
    return np.minimum.reduceat(d, np.array(starts), axis=1) - radii[pairs[:, 0]] - radii[pairs[:, 1]]


def _floor_clearance(seg: np.ndarray, body: np.ndarray, radii: np.ndarray, floor_z_m: float) -> np.ndarray:
    """``(N, B)`` lowest point of each body above the floor (m)."""
    zmin = seg[..., 2].min(axis=2)  # (N, S)
    out = np.full((seg.shape[0], len(radii)), np.inf)
    for b in range(len(radii)):
        out[:, b] = zmin[:, body == b].min(axis=1) - radii[b] - floor_z_m
    return out


def body_model(robot: Robot, radii_m=None, floor_z_m: float | None = None, n_structure: int = 512,
               seed: int = 0) -> BodyModel:
    """The capsule model and the structural exclusions of ``robot`` (module docstring).

    radii_m: ``(n_chain + 2,)`` radii (m) or None (estimated). floor_z_m: the floor height used to find the
    bodies that stand on it (None: no floor)."""
    from ..sim.sampling import uniform

    n = robot.n_chain
    radii = _default_radii(robot) if radii_m is None else np.asarray(radii_m, dtype=np.float64).reshape(-1)
    if radii.shape != (n + 2,) or not np.all(np.isfinite(radii)) or np.any(radii < 0):
        raise ValueError(f"link radii: expected {n + 2} non-negative values (base column, links 1..{n}, tool), "
                         f"got {np.ravel(radii_m).tolist()}")
    all_pairs = np.array([(i, j) for i in range(n + 2) for j in range(i + 2, n + 2)], dtype=np.int64).reshape(-1, 2)
    q = uniform(robot, n_structure, np.random.default_rng([seed, 41]))
    seg, body = body_segments(robot, q)
    touch = (_pair_distances(seg, body, radii, all_pairs) < 0).mean(axis=0) if len(all_pairs) else np.zeros(0)
    pairs = all_pairs[touch < _STRUCTURAL]
    floor = np.ones(n + 2, bool)
    floor[0] = False  # the base column stands on its mounting
    if floor_z_m is not None:
        floor &= (_floor_clearance(seg, body, radii, floor_z_m) < 0).mean(axis=0) < _STRUCTURAL
    return BodyModel(radii_m=radii, pairs=pairs, floor_bodies=floor)


def body_clear(robot: Robot, q, bm: BodyModel, floor_z_m: float | None = None, keep_out_m=(),
               chunk: int = 4096, points_m=()) -> np.ndarray:
    """``(N,)`` bool: the body (capsules of ``bm``) clears the floor, the keep-out boxes, the points
    ``points_m`` (``(3,)`` each, m, world frame: the tracker) and itself at each configuration of ``q``
    ``(N, dof)``. Evaluated in chunks of ``chunk`` configurations."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    ok = np.ones(len(q), bool)
    for s in range(0, len(q), chunk):
        seg, body = body_segments(robot, q[s : s + chunk])
        good = np.ones(len(seg), bool)
        if len(bm.pairs):
            good &= np.all(_pair_distances(seg, body, bm.radii_m, bm.pairs) >= 0, axis=1)
        if floor_z_m is not None and bm.floor_bodies.any():
            good &= np.all(_floor_clearance(seg, body, bm.radii_m, floor_z_m)[:, bm.floor_bodies] >= 0, axis=1)
        for box in keep_out_m:
            good &= ~_hits_box(seg, body, bm.radii_m, np.asarray(box, dtype=np.float64))
        for pt in points_m:
            good &= np.all(_point_clearance(seg, body, bm.radii_m, pt) >= 0, axis=1)
        ok[s : s + chunk] = good
    return ok


def _hits_box(seg: np.ndarray, body: np.ndarray, radii: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``(N,)`` whether any capsule meets the box (segments sampled every half radius, box grown by it)."""
    hit = np.zeros(len(seg), bool)
    for b in range(len(radii)):
        if b == 0:
            continue  # the base column is where the robot stands: a box around it is the user's cell, not an obstacle
        r = max(radii[b], 1e-3)
        sb = seg[:, body == b]  # (N, s, 2, 3)
        L = float(np.max(np.linalg.norm(sb[..., 1, :] - sb[..., 0, :], axis=-1), initial=0.0))
        k = max(int(np.ceil(L / (0.5 * r))), 1)
        t = np.linspace(0.0, 1.0, k + 1)[:, None]
        pts = sb[..., 0, None, :] + t * (sb[..., 1, None, :] - sb[..., 0, None, :])  # (N, s, k+1, 3)
        inside = np.all((pts >= box[0] - r) & (pts <= box[1] + r), axis=-1)
        hit |= inside.reshape(len(seg), -1).any(axis=1)
    return hit


def _point_clearance(seg: np.ndarray, body: np.ndarray, radii: np.ndarray, point) -> np.ndarray:
    """``(N, B)`` distance (m) from ``point`` to the surface of each capsule (< 0: inside)."""
    pt = np.asarray(point, dtype=np.float64).reshape(3)
    d = segment_distance(seg[..., 0, :], seg[..., 1, :], pt, pt)  # (N, S)
    out = np.empty((seg.shape[0], len(radii)))
    for b in range(len(radii)):
        out[:, b] = d[:, body == b].min(axis=1) - radii[b]
    return out


def point_clearance(robot: Robot, q, bm: BodyModel, point) -> np.ndarray:
    """``(N, B)`` distance (m) from ``point`` (``(3,)``, world frame) to each capsule of ``bm`` at the
    configurations ``q`` ``(N, dof)``; negative: the point lies that deep inside the body."""
    seg, body = body_segments(robot, q)
    return _point_clearance(seg, body, bm.radii_m, point)


def body_name(robot: Robot, b: int) -> str:
    """Name of body ``b`` of the capsule model: "base column", "link k" or "tool"."""
    if b == 0:
        return "base column"
    return "tool" if b == robot.n_chain + 1 else f"link {b}"
