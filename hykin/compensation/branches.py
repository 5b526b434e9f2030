"""Which joint solution a robot program means: KUKA ``S``/``T`` status, ABB ``confdata``, nearest joints.

A Cartesian target has up to eight closed-form solutions (shoulder, elbow, wrist) and, for joints
with a range over 360°, several 2π representations. Controllers pick one from extra data in the
program; this module computes that data from joints and picks the joints that match it.

Geometry used (hykin joint frames, :func:`hykin.kinematics.fk.fk_frames`; controller axis angles
``A = axis_signs * q``):

* wrist centre ``pw``: the point of axis 4 nearest axis 5 (the wrist centre of a spherical wrist);
* *overhead*: ``(pw - o1) · x1 < 0`` — wrist centre behind joint 1, ``x1`` the x axis of link
  frame 1 (the direction the arm points at ``A1``), ``o1`` a point on axis 1; its lean
  ``atan2(-(pw - o1) · x1, |(pw - o1) · z1|)`` (rad, > 0 overhead) is 0 with the wrist centre on axis 1;
* *elbow*: the angle ``e = atan2(((o3 - o2) × (pw - o3)) · (s3 z3), (o3 - o2) · (pw - o3))`` (rad)
  between the lower arm and the line from axis 3 to the wrist centre, signed by the side of the line
  through axes 2 and 3 the wrist centre lies on; ``e = 0`` is the stretched-elbow singularity and ``e``
  grows with ``A3`` (rotating the forearm positively about ``s3 z3``), so ``e >= 0`` ⟺ ``A3 >= φ``.

KUKA (KSS 8 manuals, "Status and Turn"; what we assumed — check one pose on the controller):
``S`` bit 0 = overhead area, bit 1 = ``A3 >= φ`` (elbow), bit 2 = ``A5 <= 0``; ``T`` bit i = ``A(i+1) < 0``.

ABB (RAPID reference, ``confdata``): ``cf1, cf4, cf6`` = quadrant ``floor(A / 90°)`` of axes 1, 4, 6;
``cfx`` = 4·(wrist centre behind axis 1) + 2·(wrist centre backward of the lower arm) + (``A5 < 0``),
"backward" being the side of the lower-arm line opposite to the wrist centre at the robot's zero
pose (the ABB table's numbering of cfx 0..7 as we read it). An arm stretched at its zero pose (UR,
Stäubli: ``e = 0`` there) takes forward as ``e > 0`` (``A3 > φ``, as KUKA's bit 1). The side is read
off the *nominal* robot: a calibrated copy of a stretched arm has ``e`` of either sign at zero, and
must name the same side forward (``reference``).

Near a singular configuration a flag can lack a solution on one side. At the reach boundary the two
elbow solutions merge at ``e = 0``; with the wrist centre on axis 1 the two shoulder solutions merge
(lean 0); at ``A5 = 0`` the two wrist solutions ``(A4, A5, A6)`` and ``(A4 + π, -A5, A6 + π)`` meet (a
spherical wrist has both on either side; a calibrated wrist whose axes do not quite meet may not). A
calibrated robot, whose singular poses lie a fraction of a degree from the nominal's, may reach a target
taught just on one side only just on the other. The matchers' ``slack_rad`` then accepts the other
elbow / overhead / wrist flag where that flag's angle (lean, ``e``, ``A5``) is within ``slack_rad`` of 0.

Hints for the hybrid solve (``margin_rad``, ``seed_robot``): the solutions of the *uncompensated*
target on the nominal or calibrated robot lie a fraction of a degree from the joints the real robot
needs (springs, the networks). A solution just beyond a joint limit may so be reached within it, and
a calibrated chain without a closed form has its branches found from a closed-form ``seed_robot``
(the nominal geometry in its base and tool; the stretched-elbow double root where the target is just
beyond the seed's reach). The matchers then take solutions up to ``margin_rad`` beyond the limits
(after every one within them), clipped onto them: the hybrid solve decides (probe report s40: targets
0.04° inside a limit, or 0.05° from the stretched elbow, were refused as "no solution with the
program's configuration data" although the real robot reaches them with exactly that ``S``/``T``).

Both assume the robot file's joints ARE the controller's axes up to a sign per joint
(``axis_signs``: the preset ``kuka-kr6-r900`` has ``q = (-A1, A2, A3, -A4, A5, -A6)``,
:func:`default_axis_signs`).
"""

from __future__ import annotations

import numpy as np

from ..kinematics.ik_solutions import LIMIT_SLACK_RAD, representation_range
from ..kinematics.robot import Robot

__all__ = [
    "abb_confdata",
    "arm_angles",
    "arm_geometry",
    "best_fitting",
    "candidate_solutions",
    "candidates",
    "default_axis_signs",
    "kuka_status",
    "match_abb_confdata",
    "match_kuka_status",
    "nearest_candidate",
    "sequential_nearest",
    "walk_nearest",
]

TWO_PI = 2.0 * np.pi
#: a joint within this angle of 0 (rad; 0.006°, the rounding of a taught literal's 3 decimals) meets its
#: KUKA T bit either way (:func:`match_kuka_status`)
T_ZERO_RAD = 1e-4
#: a controller axis within this angle of 0 (rad, 1°: corrections move joints by a fraction of a degree)
#: whose KUKA T bit the compensated joints flip has been moved across 0 by the correction: its T is
#: rewritten (noted); a T bit of an axis farther from 0 is a configuration change (programs refuse it)
T_CROSS_RAD = np.radians(1.0)
#: how far beyond a joint limit (rad) a solution of the uncompensated target still hints a branch
#: (module docstring, ``margin_rad``)
LIMIT_MARGIN_RAD = np.radians(1.0)


def default_axis_signs(robot: Robot) -> np.ndarray:
    """``(n,)`` controller axis sign per joint: ``A = sign * q``. The KUKA OPW presets (name
    ``kuka-kr*``) turn joints 1, 4, 6 the other way; every other robot is taken as ``+1``."""
    s = np.ones(robot.dof)
    if robot.name.lower().startswith("kuka-kr") and robot.dof == 6:
        s[[0, 3, 5]] = -1.0
    return s


def _closest_on_first(o1, z1, o2, z2):
    """Point of line (o1, z1) nearest line (o2, z2), batched ``(M, 3)``; parallel lines give o1."""
    w = o1 - o2
    b = np.sum(z1 * z2, -1)
    d, e = np.sum(z1 * w, -1), np.sum(z2 * w, -1)
    den = 1.0 - b * b
    t = np.where(den > 1e-12, (b * e - d) / np.where(den > 1e-12, den, 1.0), 0.0)
    return o1 + t[:, None] * z1


def arm_geometry(robot: Robot, q: np.ndarray, axis_signs=None) -> tuple[np.ndarray, np.ndarray]:
    """``(overhead (M,) bool, elbow (M,) rad)`` for joints ``q`` ``(M, n)`` (module docstring)."""
    lean, elbow = arm_angles(robot, q, axis_signs)
    return lean > 0, elbow


def arm_angles(robot: Robot, q: np.ndarray, axis_signs=None) -> tuple[np.ndarray, np.ndarray]:
    """``(lean (M,) rad, elbow (M,) rad)``: the signed angles whose signs are the overhead and elbow
    flags, 0 at their singular configurations (module docstring)."""
    from ..kinematics.fk import fk_frames

    if robot.dof < 5:
        raise ValueError(f"robot {robot.name!r}: configuration flags need a 6-axis arm, it has {robot.dof} joints")
    s = default_axis_signs(robot) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    fr = fk_frames(robot, np.asarray(q, dtype=np.float64).reshape(-1, robot.dof))
    o = fr.joint[:, :, :3, 3]
    z = fr.joint[:, :, :3, 2]
    pw = _closest_on_first(o[:, 3], z[:, 3], o[:, 4], z[:, 4])
    x1 = fr.link[:, 0, :3, 0]
    x1 = x1 - np.sum(x1 * z[:, 0], -1, keepdims=True) * z[:, 0]  # in the plane normal to axis 1
    r = pw - o[:, 0]
    lean = np.arctan2(-np.sum(r * x1, -1), np.abs(np.sum(r * z[:, 0], -1)))
    lower, upper = o[:, 2] - o[:, 1], pw - o[:, 2]
    elbow = np.arctan2(np.sum(np.cross(lower, upper) * (s[2] * z[:, 2]), -1), np.sum(lower * upper, -1))
    return lean, elbow


def kuka_status(robot: Robot, q, axis_signs=None) -> tuple[np.ndarray, np.ndarray]:
    """KUKA ``(S (M,) int, T (M,) int)`` of joints ``q`` ``(M, 6)`` rad (module docstring)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    s = default_axis_signs(robot) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    A = q * s
    overhead, elbow = arm_geometry(robot, q, s)
    S = overhead.astype(int) + 2 * (elbow >= 0).astype(int) + 4 * (A[:, 4] <= 0).astype(int)
    T = ((A < 0).astype(int) << np.arange(robot.dof)).sum(1)
    return S, T


# |e| (rad) at the zero pose below which the arm counts as stretched there: a nominal stretched arm
# gives ~1e-16 (rounding), an ABB arm ~1.5
_STRETCHED_RAD = 1e-9


def _abb_sigma(robot: Robot, s) -> float:
    """Sign making "forward of the lower arm" the side the wrist centre has at the zero pose (+1 where
    the arm is stretched there)."""
    _, e0 = arm_geometry(robot, np.clip(np.zeros((1, robot.dof)), robot.lower, robot.upper), s)
    return -1.0 if e0[0] < -_STRETCHED_RAD else 1.0


def abb_confdata(robot: Robot, q, axis_signs=None, reference: Robot | None = None) -> np.ndarray:
    """ABB ``confdata`` ``(M, 4)`` int ``[cf1, cf4, cf6, cfx]`` of joints ``q`` ``(M, 6)`` rad.
    ``reference``: the robot whose zero pose says which side of the lower arm is forward (default
    ``robot``; pass the nominal robot when ``robot`` is its calibrated copy: module docstring)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    s = np.ones(robot.dof) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    A = q * s
    overhead, elbow = arm_geometry(robot, q, s)
    backward = elbow * _abb_sigma(robot if reference is None else reference, s) < 0
    quad = np.floor(A[:, [0, 3, 5]] / (np.pi / 2) + 1e-12).astype(int)
    cfx = 4 * overhead.astype(int) + 2 * backward.astype(int) + (A[:, 4] < 0).astype(int)
    return np.concatenate([quad, cfx[:, None]], axis=1)


def candidate_solutions(robot: Robot, T_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every nominal solution of each target, with every 2π representation within the limits.

    ``T_world`` ``(N, 4, 4)`` (world frame of ``robot``). Returns ``(q (N, K, n), ok (N, K))``.
    """
    from ..kinematics.ik import ik

    br = ik(robot, T_world, all_branches=True)
    q, ok = br.q, br.success.copy()
    rev = robot.revolute
    wide = np.flatnonzero(rev & (robot.upper - robot.lower > TWO_PI - 1e-9))
    if wide.size:
        # shifts of -2π, 0, +2π on each joint with a range over 360°: at most 3^k representations
        grid = np.stack(np.meshgrid(*([np.array([-1.0, 0.0, 1.0])] * wide.size), indexing="ij"), -1).reshape(-1, wide.size)
        shift = np.zeros((len(grid), robot.dof))
        shift[:, wide] = grid * TWO_PI
        q = (q[:, :, None, :] + shift[None, None]).reshape(len(q), -1, robot.dof)
        ok = np.repeat(ok, len(grid), axis=1)
    inside = np.all((q >= robot.lower - 1e-9) & (q <= robot.upper + 1e-9), axis=-1)
    return q, ok & inside & np.isfinite(q).all(-1)


def candidates(robot: Robot, T_world, margin_rad: float = 0.0,
               seed_robot: Robot | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Branch hints of each target (module docstring): ``(q (N, K, n), ok (N, K), penalty (N, K))``,
    every solution of ``robot`` and (with ``seed_robot``) every closed-form solution of ``seed_robot``
    (unpolished), with every 2π representation within the limits widened by ``margin_rad``; ``penalty``:
    the matchers' extra cost, 100 + how far (rad, summed over the joints) a solution lies beyond the limits,
    plus 50 for a seed robot's unpolished one (at the reach boundary its clamped double root sits exactly
    on the stretched elbow, either flag: ``robot``'s own solutions come first); 0 for ``robot``'s own
    within the limits. Without margin and seed robot: :func:`candidate_solutions`."""
    import warnings

    from ..kinematics.ik import ik, ik_closed_form
    from ..kinematics.ik_closed_form import has_closed_form
    from ..kinematics.ik_reasons import open_revolute_limits

    T = np.asarray(T_world, dtype=np.float64)
    if margin_rad <= 0 and seed_robot is None:
        q, ok = candidate_solutions(robot, T)
        return q, ok, np.zeros(ok.shape)
    sr = None if seed_robot is None else open_revolute_limits(seed_robot)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # limits opened: a solution a hair beyond a limit is a hint, not nothing (ik keeps only those within)
        opened = open_revolute_limits(robot)
        br = ik(opened, T, all_branches=True, seed_robot=sr)
        q, ok = np.asarray(br.q, dtype=np.float64), np.asarray(br.success, dtype=bool)
        if sr is not None and not has_closed_form(robot):  # its own search too: near the reach boundary the
            # seeds' two elbow roots are one clamped point, whose polish finds one of the robot's two solutions
            own = ik(opened, T, all_branches=True)
            q = np.concatenate([q, np.asarray(own.q, dtype=np.float64)], axis=1)
            ok = np.concatenate([ok, np.asarray(own.success, dtype=bool)], axis=1)
        seed = np.zeros(ok.shape)
        if sr is not None and has_closed_form(sr):  # its branches as found: the polish may lose one at a singularity
            cf = ik_closed_form(sr, T, tol_m=np.inf, tol_rad=np.inf)
            q = np.concatenate([q, cf.q], axis=1)
            ok = np.concatenate([ok, cf.valid & np.isfinite(cf.q).all(-1)], axis=1)
            seed = np.concatenate([seed, np.full(cf.valid.shape, 50.0)], axis=1)
    n = robot.dof
    rev = robot.revolute
    lo, hi = robot.lower - margin_rad, robot.upper + margin_rad
    wide = np.flatnonzero(rev & (hi - lo >= TWO_PI - 1e-9))
    narrow = rev & (hi - lo < TWO_PI - 1e-9)
    qz = np.nan_to_num(q)
    start = lo - 1e-9  # a joint whose widened range is under 2π has one representation from there
    qz = np.where(narrow, start + np.mod(qz - start, TWO_PI), qz)
    if wide.size:  # -2π, 0, +2π on each wider joint (the opened IK returns them within ±2π)
        grid = np.stack(np.meshgrid(*([np.array([-1.0, 0.0, 1.0])] * wide.size), indexing="ij"), -1).reshape(-1, wide.size)
        shift = np.zeros((len(grid), n))
        shift[:, wide] = grid * TWO_PI
        qz = (qz[:, :, None, :] + shift[None, None]).reshape(len(qz), -1, n)
        ok = np.repeat(ok, len(grid), axis=1)
        seed = np.repeat(seed, len(grid), axis=1)
    inside = np.all((qz >= lo - 1e-9) & (qz <= hi + 1e-9), axis=-1)
    excess = (np.maximum(robot.lower - qz, 0.0) + np.maximum(qz - robot.upper, 0.0)).sum(-1)
    ok = ok & inside & np.isfinite(qz).all(-1)
    penalty = np.where(excess > 0, 100.0 + excess, 0.0) + seed
    return np.where(ok[..., None], qz, np.nan), ok, np.where(ok, penalty, 0.0)


def _pick(q: np.ndarray, ok: np.ndarray, cost: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Per target the candidate of least ``cost`` among ``ok & allowed``; NaN rows where none."""
    c = np.where(ok & allowed, cost, np.inf)
    k = np.argmin(c, axis=1)
    out = q[np.arange(len(q)), k].copy()
    out[~np.isfinite(c[np.arange(len(q)), k])] = np.nan
    return out


def _flag_match(robot: Robot, q: np.ndarray, got: np.ndarray, want: np.ndarray, bits: tuple[int, int, int], axis_signs,
                slack_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """``(allowed (N, K) bool, extra cost (N, K))``: candidates ``q`` ``(N, K, n)`` whose flags ``got``
    equal ``want``, and, with ``slack_rad > 0``, those whose differing flags are only the overhead /
    elbow / wrist bits ``bits`` with that flag's angle (lean, elbow, ``A5``) within ``slack_rad`` of 0
    (module docstring), at a cost that puts every exact match first."""
    exact = got == want
    if slack_rad <= 0:
        return exact, np.zeros(got.shape)
    s = np.ones(robot.dof) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    qf = np.nan_to_num(q.reshape(-1, robot.dof))
    lean, e = arm_angles(robot, qf, s)
    near = (np.where(np.abs(lean) <= slack_rad, bits[0], 0) | np.where(np.abs(e) <= slack_rad, bits[1], 0)
            | np.where(np.abs(qf[:, 4]) <= slack_rad, bits[2], 0)).reshape(got.shape)
    allowed = (np.bitwise_xor(got, want) & ~near) == 0
    return allowed, np.where(exact, 0.0, 1e6)


def match_kuka_status(robot: Robot, T_world, S, T=None, axis_signs=None, slack_rad: float = 0.0,
                      margin_rad: float = 0.0, seed_robot: Robot | None = None) -> np.ndarray:
    """Nominal joints ``(N, n)`` of each target with status ``S`` (exact) and turn ``T`` (fewest
    differing bits, a joint within :data:`T_ZERO_RAD` of 0 meeting its bit either way; ``-1`` or ``None`` =
    not given: the representation nearest zero). NaN rows where no
    nominal solution has that ``S``. ``slack_rad``: where none has, accept the other overhead / elbow /
    wrist bit within that angle of its singular configuration (module docstring). ``margin_rad``,
    ``seed_robot``: branch hints (:func:`candidates`): solutions up to ``margin_rad`` beyond a limit count
    after those within the limits and come back clipped onto it."""
    q, ok, penalty = candidates(robot, np.asarray(T_world, dtype=np.float64), margin_rad, seed_robot)
    N, K, n = q.shape
    signs = default_axis_signs(robot) if axis_signs is None else axis_signs
    Sc, Tc = kuka_status(robot, np.nan_to_num(q.reshape(-1, n)), signs)
    Sc, Tc = Sc.reshape(N, K), Tc.reshape(N, K)
    S = np.asarray(S, dtype=int).reshape(N, 1)
    Tg = np.full((N, 1), -1) if T is None else np.asarray(T, dtype=int).reshape(N, 1)
    # a joint within T_ZERO_RAD of 0 (a point taught at A6 = 0 solves to ±1e-12) meets its T bit either
    # way: its representation is then the one nearest zero (the taught one), not a full turn away
    A = np.nan_to_num(q.reshape(-1, n)) * np.asarray(signs, dtype=np.float64)
    either = ((np.abs(A) <= T_ZERO_RAD).astype(int) << np.arange(n)).sum(1).reshape(N, K)
    diff = np.bitwise_xor(Tc, np.maximum(Tg, 0)) & ~either
    bits = np.zeros_like(diff, dtype=float)
    for b in range(n):
        bits += (diff >> b) & 1
    allowed, extra = _flag_match(robot, q, Sc, S, (1, 2, 4), signs, slack_rad)
    # T bits first (a differing bit is a full turn or another configuration), then beyond a limit, then an
    # unpolished seed, then |q|
    cost = np.where(Tg >= 0, bits * 1e3, 0.0) + np.abs(np.nan_to_num(q)).sum(-1) + extra + penalty
    return _clip(robot, _pick(q, ok, cost, allowed))


def match_abb_confdata(robot: Robot, T_world, conf, axis_signs=None, reference: Robot | None = None,
                       slack_rad: float = 0.0, margin_rad: float = 0.0, seed_robot: Robot | None = None) -> np.ndarray:
    """Nominal joints ``(N, n)`` with ``cfx`` equal and the quadrants ``cf1, cf4, cf6`` nearest the
    given ``conf`` ``(N, 4)`` (ties: the joints nearest zero); NaN rows where no nominal solution has
    that ``cfx``. ``reference``: as
    :func:`abb_confdata`; ``slack_rad``, ``margin_rad``, ``seed_robot``: as :func:`match_kuka_status`
    (``cfx`` bits 2, 1 and 0)."""
    q, ok, penalty = candidates(robot, np.asarray(T_world, dtype=np.float64), margin_rad, seed_robot)
    N, K, n = q.shape
    cc = abb_confdata(robot, np.nan_to_num(q.reshape(-1, n)), axis_signs, reference).reshape(N, K, 4)
    conf = np.asarray(conf, dtype=int).reshape(N, 1, 4)
    allowed, extra = _flag_match(robot, q, cc[..., 3], conf[..., 3], (4, 2, 1), axis_signs, slack_rad)
    # quadrants first; then (axes 2, 3, 5 carry none) the representation nearest zero, as a controller
    # whose axes 2, 3 stay within ±180° has them (a joint range over 360° has several); beyond a limit and
    # unpolished seeds last
    cost = np.abs(cc[..., :3] - conf[..., :3]).sum(-1) + 1e-3 * np.abs(np.nan_to_num(q)).sum(-1) + extra + penalty
    return _clip(robot, _pick(q, ok, cost, allowed))


def _clip(robot: Robot, q: np.ndarray) -> np.ndarray:
    """``q`` clipped onto the joint limits (a hint just beyond one); NaN rows stay NaN."""
    return np.where(np.isfinite(q), np.clip(q, robot.lower, robot.upper), np.nan)


class Candidates:
    """Solutions ``q`` ``(N, K, n)`` of N targets (valid where ``ok`` ``(N, K)`` and finite), prepared
    once for :meth:`nearest` (the 2π ranges within the limits do not depend on the reference)."""

    def __init__(self, robot: Robot, q: np.ndarray, ok: np.ndarray):
        q = np.asarray(q, dtype=np.float64)
        self.qz = np.nan_to_num(q)
        self.k_lo, self.k_hi = representation_range(self.qz, robot.lower, robot.upper)
        rev = robot.revolute  # (n,) like q (mimic joints excluded)
        self.shift = TWO_PI * (rev & (self.k_lo <= self.k_hi))  # 2π where a revolute joint can move into the limits
        self.valid = np.asarray(ok, dtype=bool) & np.isfinite(q).all(-1)
        self.lower, self.upper = robot.lower, robot.upper
        self.lo, self.hi = robot.lower - LIMIT_SLACK_RAD, robot.upper + LIMIT_SLACK_RAD

    def nearest(self, i: int, cur: np.ndarray) -> np.ndarray | None:
        """Of target ``i``'s valid solutions, each in its 2π representation nearest ``cur`` ``(n,)``
        within the limits, the one nearest ``cur``; None when no valid one is within the limits."""
        qz = self.qz[i]
        k = np.clip(np.round((cur - qz) / TWO_PI), self.k_lo[i], self.k_hi[i])
        qq = qz + k * self.shift[i]  # nearest_representation (revolute joints), q itself elsewhere
        inside = self.valid[i] & ((qq >= self.lo) & (qq <= self.hi)).all(1)
        if not inside.any():
            return None
        dq = qq - cur
        d = np.where(inside, np.sqrt((dq * dq).sum(1)), np.inf)
        return np.clip(qq[int(np.argmin(d))], self.lower, self.upper)  # a rounding beyond a limit: onto it

    def nearest_each(self, cur: np.ndarray) -> np.ndarray:
        """``(N, n)``: row ``i`` is :meth:`nearest` ``(i, cur[i])`` for ``cur`` ``(N, n)``, all rows at once;
        NaN rows where none is valid within the limits or ``cur[i]`` is not finite."""
        cur = np.asarray(cur, dtype=np.float64)
        good = np.isfinite(cur).all(1)
        c = np.where(good[:, None], cur, 0.0)[:, None, :]
        k = np.clip(np.round((c - self.qz) / TWO_PI), self.k_lo, self.k_hi)
        qq = self.qz + k * self.shift
        inside = self.valid & ((qq >= self.lo) & (qq <= self.hi)).all(-1)
        dq = qq - c
        d = np.where(inside, np.sqrt((dq * dq).sum(-1)), np.inf)
        out = np.clip(qq[np.arange(len(qq)), np.argmin(d, axis=1)], self.lower, self.upper)
        out[~(good & inside.any(1))] = np.nan
        return out


def nearest_candidate(robot: Robot, q: np.ndarray, ok: np.ndarray, cur: np.ndarray) -> np.ndarray | None:
    """Of the solutions ``q`` ``(K, n)`` (valid where ``ok``), each in its 2π representation nearest
    ``cur`` ``(n,)`` within the limits, the one nearest ``cur``; None when no valid one is within the limits."""
    return Candidates(robot, np.asarray(q)[None], np.asarray(ok)[None]).nearest(0, cur)


def best_fitting(ok: np.ndarray, pos_err_m: np.ndarray, ang_err_rad: np.ndarray, factor: float = 10.0,
                 floor: float = 1e-6) -> np.ndarray:
    """``ok`` ``(N, K)`` restricted to the solutions whose residual (m + rad) is within ``factor`` times
    their target's best plus ``floor``: of an under-actuated arm's least-squares solutions, the branches
    that fit the target (the other elbow of a SCARA whose axes are not quite parallel tilts the tool
    ~0.1° otherwise: it does not reach a pose the first reaches to 1e-3°). Exact solutions (residual
    ~1e-10) all stay."""
    with np.errstate(invalid="ignore"):
        res = np.asarray(pos_err_m, dtype=np.float64) + np.asarray(ang_err_rad, dtype=np.float64)
    res = np.where(ok & np.isfinite(res), res, np.inf)
    best = res.min(axis=1, keepdims=True)
    return ok & (res <= factor * best + floor)


def sequential_nearest(robot: Robot, T_world, q_start=None, polish: bool = True,
                       least_squares: tuple[float, float] | None = None) -> np.ndarray:
    """Joints ``(N, n)`` a controller moving through the targets in order would pick: each target's
    nominal solution nearest the previous one (the first nearest ``q_start``, default zero clipped into
    the limits), over every branch and 2π representation within the limits. NaN rows for unreachable
    targets (the walk continues from the last reached joints).

    ``polish=False`` (branch hints, refined afterwards anyway): a robot's own closed-form solutions as
    found (to 1e-9 m / rad), not polished to 1e-10 by LM (:func:`hykin.kinematics.ik.ik`'s ``polish``):
    the polish was a quarter of a compensated batch's time. ``least_squares`` ``(m, rad)``: an
    under-actuated arm's (fewer than 6 joints) least-squares solutions within these count too
    (:func:`hykin.kinematics.ik.ik`: it matches an arbitrary pose only in that sense), those that fit
    it best (:func:`best_fitting`)."""
    from ..kinematics.ik import ik

    br = ik(robot, np.asarray(T_world, dtype=np.float64), all_branches=True, polish=polish, least_squares=least_squares)
    q = np.asarray(br.q, dtype=np.float64).reshape(len(br.q), -1, robot.dof)
    ok = np.asarray(br.success, dtype=bool).reshape(len(q), -1)
    if least_squares is not None:
        ok = best_fitting(ok, br.pos_err_m, br.ang_err_rad)
    return walk_nearest(robot, q, ok, q_start)


def walk_nearest(robot: Robot, q: np.ndarray, ok: np.ndarray, q_start=None) -> np.ndarray:
    """Joints ``(N, n)``: each row's candidate of ``q`` ``(N, K, n)`` (valid where ``ok`` ``(N, K)``)
    nearest the previous row's pick, over every 2π representation within the limits (the first nearest
    ``q_start``, default zero clipped into the limits); NaN rows where none is valid (the walk continues
    from the last pick)."""
    cur = np.clip(np.zeros(robot.dof), robot.lower, robot.upper) if q_start is None else np.asarray(q_start, float)
    out = np.full((len(q), robot.dof), np.nan)
    cand = Candidates(robot, q, ok)
    if _walk is not None:  # compiled: the same choices as Candidates.nearest, row after row
        _walk(cand.qz, cand.k_lo, cand.k_hi, cand.shift, cand.valid, ok.any(1), cand.lo, cand.hi,
              np.asarray(cand.lower, np.float64), np.asarray(cand.upper, np.float64), np.array(cur, np.float64), out)
        return out
    # a walk: each choice depends on the previous one (N steps over K branches each)
    for i in range(len(q)):
        if ok[i].any():
            pick = cand.nearest(i, cur)
            if pick is not None:
                cur = out[i] = pick
    return out


def _compile_walk():
    from ..kinematics.fk import HAVE_NUMBA

    if not HAVE_NUMBA:
        return None
    import math

    import numba

    @numba.njit(cache=True, nogil=True)
    def walk(qz, k_lo, k_hi, shift, valid, any_ok, lo, hi, lower, upper, cur, out):  # pragma: no cover - compiled
        """:meth:`Candidates.nearest` for each row in turn from ``cur``, into ``out`` (NaN rows stay)."""
        N, K, n = qz.shape
        qq = np.empty((K, n))
        for i in range(N):
            if not any_ok[i]:
                continue
            best, best_d = -1, math.inf
            for k in range(K):
                inside = valid[i, k]
                for j in range(n):
                    m = np.rint((cur[j] - qz[i, k, j]) / (2.0 * math.pi))
                    m = min(max(m, k_lo[i, k, j]), k_hi[i, k, j])
                    v = qz[i, k, j] + m * shift[i, k, j]
                    qq[k, j] = v
                    if not (v >= lo[j] and v <= hi[j]):
                        inside = False
                if inside:
                    d = 0.0
                    for j in range(n):
                        d += (qq[k, j] - cur[j]) ** 2
                    d = math.sqrt(d)
                    if d < best_d:
                        best, best_d = k, d
            if best >= 0:
                for j in range(n):
                    cur[j] = min(max(qq[best, j], lower[j]), upper[j])
                    out[i, j] = cur[j]

    return walk


_walk = _compile_walk()


#: a hint this near the wrist singularity (``|q5|``, rad) has an arbitrary A4/A6 split (:func:`wrist_split_seeds`)
WRIST_NEAR_RAD = np.radians(10.0)
WRIST_STEP_DEG = 30.0


def wrist_split_seeds(nom: Robot, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, seeds)``: for each hint of ``h`` ``(M, n)`` near the wrist singularity (a 6-joint-or-more arm,
    ``|q5|`` under :data:`WRIST_NEAR_RAD`) the hints with the A4/A6 split turned in 30° steps (q4 + δ,
    q6 ∓ δ: the same flange orientation at q5 = 0; δ = 30, -30, 60, ..., 180°, in that order), each into
    its representation nearest zero within the limits; ``rows`` ``(K,)`` the index into ``h`` of each seed.
    Near it the hint's split is the closed form's arbitrary choice, and the real robot's solutions can lie
    90° along that valley, farther than a solve slides (probe reports s40, s41 AL: wrist-singular targets
    refused with 0.03-0.5 mm residuals)."""
    from ..kinematics.fk import fk_frames

    h = np.asarray(h, dtype=np.float64)
    none = np.zeros(0, dtype=np.int64), np.zeros((0, nom.dof))
    if nom.dof < 6 or not len(h):
        return none
    q5 = (np.nan_to_num(h[:, 4], nan=np.inf) + np.pi) % (2 * np.pi) - np.pi  # a turn away is as near
    rows = np.flatnonzero(np.isfinite(h).all(1) & (np.abs(q5) < WRIST_NEAR_RAD))
    if not rows.size:
        return none
    z = fk_frames(nom, h[rows]).joint[:, :, :3, 2]
    same = np.sign(np.sum(z[:, 3] * z[:, 5], -1))  # axes 4 and 6 aligned (+1) or opposed (-1) at q5 = 0
    steps = np.arange(1, int(180 / WRIST_STEP_DEG) + 1) * WRIST_STEP_DEG
    deltas = np.radians([d for a in steps for d in ((a, -a) if a < 180 else (a,))])
    H = np.repeat(h[rows], len(deltas), axis=0)
    d = np.tile(deltas, len(rows))
    H[:, 3] += d
    H[:, 5] -= np.repeat(same, len(deltas)) * d
    rev = nom.revolute
    H = np.where(rev, (H + np.pi) % (2 * np.pi) - np.pi, H)
    return np.repeat(rows, len(deltas)), np.clip(H, nom.lower, nom.upper)
