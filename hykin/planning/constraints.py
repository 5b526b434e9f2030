"""Where a pose may be measured: joint region, Cartesian box, tracker line of sight, keep-out boxes.

A pose ``q`` is *feasible* for a :class:`Constraints` when

* every joint lies in the working region ``[lower, upper]`` (within the joint limits);
* the reflector point ``p`` (TCP, or a point ``reflector_offset_m`` in the tool frame) lies in the
  Cartesian ``box_m`` (world frame = the frame of :func:`hykin.kinematics.fk.fk`, ``robot.base`` applied);
* line of sight, when a tracker position is given: the angle between the reflector's axis ``n``
  (tool-frame ``reflector_axis``, default tool z) and the direction to the tracker ``t - p`` is at
  most ``max_incidence_deg`` (a 1.5" SMR accepts about ±30°, a 6-D probe such as a T-Mac ±45°),
  the reflector is at least ``min_range_m`` from the tracker, and the segment from the tracker to
  ``p`` crosses no keep-out box;
* the reflector point is inside no keep-out box;
* the robot's body (capsules along the chain, :mod:`.bodies`) clears itself, the floor plane
  ``z = floor_z_m`` (world frame), the keep-out boxes and the tracker point (``body``, on by default).

Refused up front by :meth:`Constraints.check`, before any candidate is drawn: a tracker farther than
``max_tracker_distance_m`` (:data:`MAX_TRACKER_DISTANCE_M`, 100 m) from the robot base (a unit slip),
inside a keep-out box, or inside the robot's body in every pose of the region; a Cartesian box whose
nearest point lies beyond the robot's reach.

The robot's own links are **not** checked as obstacles of the beam; a user who needs it adds
keep-out boxes around fixed obstacles, and the incidence cone already removes most self-occlusion
by the wrist.

Boxes are axis-aligned in the world frame, ``(2, 3)`` arrays ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``
(m). All tests are vectorised over ``(N, dof)`` joints; FK is :func:`hykin.kinematics.fk.fk` (the rigid model:
joint deflection moves the TCP by millimetres, far below what changes an incidence angle).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..kinematics.fk import fk
from ..kinematics.robot import Robot, robot_reach_m
from .bodies import BodyModel, body_clear, body_model, body_name, point_clearance

__all__ = [
    "MAX_TRACKER_DISTANCE_M",
    "Constraints",
    "check_box_reach",
    "check_tracker",
    "PlanningError",
    "feasible",
    "incidence_deg",
    "parse_box",
    "parse_region",
    "reflector_pose",
    "region_bounds",
    "segment_hits_box",
]


#: Farthest tracker from the robot base (m): laser trackers measure out to about 80 m radius (e.g. 160 m
#: diameter with an SMR), cameras and 6-D probes much less, so a tracker beyond 100 m is a unit slip
#: (millimetres given as metres) or a wrong frame. ``Constraints.max_tracker_distance_m`` lifts it.
MAX_TRACKER_DISTANCE_M = 100.0


class PlanningError(ValueError):
    """Bad planning request (region, box, tracker, sizes) or no feasible pose."""


@dataclass
class Constraints:
    """Measurement constraints of a plan (module docstring). Lengths m, angles rad unless named _deg.

    lower/upper: ``(dof,)`` working region (None: the joint limits). box_m: ``(2, 3)`` Cartesian box
    for the reflector point or None. tracker_m: ``(3,)`` tracker position (world frame) or None (no
    line-of-sight test). max_incidence_deg: cone half-angle of the reflector. reflector_offset_m:
    ``(3,)`` reflector point in the tool frame (0 = TCP). reflector_axis: ``(3,)`` reflector normal
    in the tool frame. keep_out_m: list of ``(2, 3)`` boxes. min_range_m: closest tracker distance.
    floor_z_m: floor height (world frame) or None. body: check the robot's body (self-collision,
    floor, keep-out boxes). link_radii_m: ``(n_chain + 2,)`` capsule radii or None (estimated,
    :mod:`.bodies`). bodies: the capsule model, set by :meth:`check`. max_tracker_distance_m: farthest
    tracker from the robot base (m; default :data:`MAX_TRACKER_DISTANCE_M`, ``inf`` lifts it). length_unit:
    the unit the user typed lengths in ("m" or "mm"), for the hints of messages only.
    """

    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    box_m: np.ndarray | None = None
    tracker_m: np.ndarray | None = None
    max_incidence_deg: float = 30.0
    reflector_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reflector_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    keep_out_m: list = field(default_factory=list)
    min_range_m: float = 0.0
    floor_z_m: float | None = None
    body: bool = True
    link_radii_m: np.ndarray | None = None
    bodies: BodyModel | None = None
    max_tracker_distance_m: float = MAX_TRACKER_DISTANCE_M
    length_unit: str = "m"

    def check(self, robot: Robot) -> Constraints:
        """Validated copy with the region resolved against ``robot`` (raises :class:`PlanningError`).

        Refused before any sampling: a tracker farther than ``max_tracker_distance_m`` from the robot
        base, inside a keep-out box or inside the robot's body in every pose of the region, and a
        Cartesian box beyond the robot's reach (:func:`check_tracker`, :func:`check_box_reach`)."""
        lo, hi = region_bounds(robot, self.lower, self.upper)
        box = None if self.box_m is None else _box(self.box_m, "box")
        tr = None
        if self.tracker_m is not None:
            tr = np.asarray(self.tracker_m, dtype=np.float64).reshape(-1)
            if tr.shape != (3,) or not np.isfinite(tr).all():
                raise PlanningError(f"tracker position must be 3 finite numbers (m), got {_plain(self.tracker_m)}")
        if not (0.0 < float(self.max_incidence_deg) <= 90.0):
            raise PlanningError(f"max incidence must be in (0, 90] deg, got {self.max_incidence_deg}")
        ax = np.asarray(self.reflector_axis, dtype=np.float64).reshape(-1)
        if ax.shape != (3,) or not np.linalg.norm(ax) > 0:
            raise PlanningError(f"reflector axis must be a non-zero 3-vector, got {_plain(self.reflector_axis)}")
        off = np.asarray(self.reflector_offset_m, dtype=np.float64).reshape(-1)
        if off.shape != (3,) or not np.isfinite(off).all():
            raise PlanningError(f"reflector offset must be 3 finite numbers (m), got {_plain(self.reflector_offset_m)}")
        ko = [_box(b, f"keep-out box {k + 1}") for k, b in enumerate(self.keep_out_m)]
        floor = None if self.floor_z_m is None else float(self.floor_z_m)
        if floor is not None and not np.isfinite(floor):
            raise PlanningError(f"floor height must be a finite number (m), got {self.floor_z_m!r}")
        bodies = None
        if self.body:
            try:
                bodies = body_model(robot, self.link_radii_m, floor)
            except ValueError as e:
                raise PlanningError(str(e)) from None
        if box is not None:
            check_box_reach(robot, box, off, self.length_unit)
        if tr is not None:
            check_tracker(robot, tr, ko, bodies, lo, hi, self.max_tracker_distance_m, self.length_unit)
        return replace(self, lower=lo, upper=hi, box_m=box, tracker_m=tr, max_incidence_deg=float(self.max_incidence_deg),
                       reflector_offset_m=off, reflector_axis=ax / np.linalg.norm(ax), keep_out_m=ko,
                       min_range_m=float(self.min_range_m), floor_z_m=floor, body=bool(self.body),
                       link_radii_m=None if bodies is None else bodies.radii_m, bodies=bodies)


def _plain(v) -> str:
    """Numbers of ``v`` as plain text ``"0, 0, 0"`` (no numpy repr in a message)."""
    try:
        return ", ".join(f"{float(x):g}" for x in np.ravel(np.asarray(v, dtype=np.float64)))
    except (TypeError, ValueError):
        return repr(v)


def check_tracker(robot: Robot, tracker_m: np.ndarray, keep_out_m, bodies: BodyModel | None, lower, upper,
                  max_distance_m: float | None = MAX_TRACKER_DISTANCE_M, length_unit: str = "m",
                  n_poses: int = 256) -> None:
    """Refuse (:class:`PlanningError`) a tracker position (m, world frame) that no plan can use: farther
    than ``max_distance_m`` from the robot base (None: no bound), inside a keep-out box (every beam
    crosses it), or inside the robot's body (capsules of ``bodies``) in each of ``n_poses`` spread
    poses of the region ``[lower, upper]`` (the base column is fixed: a tracker in it is always inside).
    ``length_unit``: the unit the user typed lengths in, for the hint of the message only."""
    base = robot.base[:3, 3]
    dist = float(np.linalg.norm(tracker_m - base))
    if max_distance_m is not None and dist > max_distance_m:
        hint = ("millimetres given as metres? use --length-unit mm" if length_unit == "m"
                else "no laser tracker or camera measures that far")
        raise PlanningError(f"--tracker is {dist:.6g} m from the robot base, farther than the {max_distance_m:g} m "
                            f"any laser tracker or camera reaches (--max-tracker-distance-m lifts it): {hint}")
    for k, b in enumerate(keep_out_m):
        if np.all((tracker_m >= b[0]) & (tracker_m <= b[1])):
            raise PlanningError(f"the tracker lies inside keep-out box {k + 1}: every beam would cross it "
                                f"(move the tracker or the box)")
    if bodies is None:
        return
    from ..sim.sampling import uniform

    q = uniform(robot, n_poses, np.random.default_rng([0, 43]), lower=lower, upper=upper)
    cl = point_clearance(robot, q, bodies, tracker_m)  # (N, B), < 0 inside
    if np.all(cl.min(axis=1) < 0):
        i = int(np.argmax(cl.min(axis=1)))  # the pose where it is least deep inside
        b = int(np.argmin(cl[i]))
        raise PlanningError(f"the tracker lies {-cl[i, b]:.3g} m inside the robot's {body_name(robot, b)} (capsule radius "
                            f"{bodies.radii_m[b]:.3g} m, --link-radii) in every pose of the region: give a tracker "
                            f"position outside the robot, in the world frame ([base] of the robot file applied)")


def check_box_reach(robot: Robot, box_m: np.ndarray, reflector_offset_m=None, length_unit: str = "m") -> None:
    """Refuse (:class:`PlanningError`) a Cartesian box (m, world frame) whose nearest point is farther
    from the robot base than the robot reaches (:func:`robot_reach_m` plus the reflector offset).
    ``length_unit``: the unit the user typed lengths in, for the hint of the message only."""
    base = robot.base[:3, 3]
    off = 0.0 if reflector_offset_m is None else float(np.linalg.norm(reflector_offset_m))
    reach = robot_reach_m(robot) + off
    dist = _box_distance(base, box_m)
    if dist > reach:
        slip = length_unit == "m" and _box_distance(base, box_m * 1e-3) <= reach
        raise PlanningError(f"no pose can meet the constraints: the --box's nearest point is {dist:.4g} m from the robot "
                            f"base, beyond its reach of {reach:.4g} m (box in the world frame, [base] applied"
                            + ("; millimetres given as metres? use --length-unit mm)" if slip else ")"))


def _box_distance(p: np.ndarray, box_m: np.ndarray) -> float:
    """Distance (m) from point ``p`` to the nearest point of the box ``(2, 3)`` (0 inside)."""
    return float(np.linalg.norm(np.clip(p, box_m[0], box_m[1]) - p))


def _box(b, what: str) -> np.ndarray:
    a = np.asarray(b, dtype=np.float64)
    if a.size != 6 or not np.isfinite(a).all():
        raise PlanningError(f"{what}: expected 6 finite numbers xmin,ymin,zmin,xmax,ymax,zmax (m), got {np.ravel(a).tolist()}")
    a = a.reshape(2, 3)
    if np.any(a[0] >= a[1]):
        raise PlanningError(f"{what}: min must be below max on every axis, got {a.tolist()}")
    return a


def region_bounds(robot: Robot, lower=None, upper=None, angle_unit: str = "rad") -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` ``(dof,)`` of the working region, checked to lie within the joint limits.

    ``angle_unit`` ("rad" or "deg"): the unit the user typed revolute ranges in, for messages only
    (the bounds are rad, m for prismatic joints)."""
    lo = robot.lower.copy() if lower is None else np.asarray(lower, dtype=np.float64).reshape(-1)
    hi = robot.upper.copy() if upper is None else np.asarray(upper, dtype=np.float64).reshape(-1)
    if lo.shape != (robot.dof,) or hi.shape != (robot.dof,):
        raise PlanningError(f"region: expected {robot.dof} joint ranges, got {lo.size}")
    for j in range(robot.dof):
        f, u = _joint_unit(robot, j, angle_unit)
        rng = f"[{lo[j] * f:.6g}, {hi[j] * f:.6g}] {u}"
        if not (np.isfinite(lo[j]) and np.isfinite(hi[j]) and lo[j] < hi[j]):
            raise PlanningError(f"region: joint {j + 1} range {rng} is empty or not finite")
        if lo[j] < robot.lower[j] - 1e-9 or hi[j] > robot.upper[j] + 1e-9:
            raise PlanningError(f"region: joint {j + 1} range {rng} exceeds the joint limits "
                                f"[{robot.lower[j] * f:.6g}, {robot.upper[j] * f:.6g}] {u}")
    return np.maximum(lo, robot.lower), np.minimum(hi, robot.upper)


def _joint_unit(robot: Robot, j: int, angle_unit: str) -> tuple[float, str]:
    """Factor from SI to the display unit of independent joint ``j``, and the unit's name."""
    if robot.independent_joint_type[j] != "revolute":
        return 1.0, "m"
    return (180.0 / np.pi, "deg") if angle_unit == "deg" else (1.0, "rad")


def reflector_pose(robot: Robot, q, c: Constraints) -> tuple[np.ndarray, np.ndarray]:
    """Reflector points ``(N, 3)`` (m) and unit normals ``(N, 3)``, world frame."""
    T = fk(robot, np.asarray(q, dtype=np.float64).reshape(-1, robot.dof))
    R = T[:, :3, :3]
    p = T[:, :3, 3] + R @ np.asarray(c.reflector_offset_m, dtype=np.float64)
    n = R @ (np.asarray(c.reflector_axis, dtype=np.float64) / np.linalg.norm(c.reflector_axis))
    return p, n


def incidence_deg(p: np.ndarray, n: np.ndarray, tracker_m: np.ndarray) -> np.ndarray:
    """``(N,)`` angle (deg) between the reflector normals ``n`` and the directions to the tracker."""
    v = np.asarray(tracker_m, dtype=np.float64)[None] - p
    d = np.linalg.norm(v, axis=1)
    cosang = np.einsum("ij,ij->i", v, n) / np.maximum(d, 1e-300)
    return np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))


def segment_hits_box(a: np.ndarray, b: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``(N,)`` whether the segments ``a -> b`` (``(N, 3)`` or ``(3,)`` each) meet the box (slab test)."""
    a, b = np.broadcast_arrays(np.atleast_2d(a).astype(np.float64), np.atleast_2d(b).astype(np.float64))
    d = b - a
    t0 = np.zeros(len(a))
    t1 = np.ones(len(a))
    for k in range(3):
        dk = d[:, k]
        par = np.abs(dk) < 1e-15
        inside = (a[:, k] >= box[0, k]) & (a[:, k] <= box[1, k])
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (box[0, k] - a[:, k]) / dk
            tb = (box[1, k] - a[:, k]) / dk
        lo = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
        hi = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
        t0 = np.maximum(t0, lo)
        t1 = np.minimum(t1, hi)
    return t0 <= t1


def feasible(robot: Robot, q, c: Constraints) -> np.ndarray:
    """``(N,)`` bool: which joints ``q`` ``(N, dof)`` satisfy every constraint of ``c`` (module docstring)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    lo = robot.lower if c.lower is None else c.lower
    hi = robot.upper if c.upper is None else c.upper
    ok = np.all((q >= lo - 1e-12) & (q <= hi + 1e-12), axis=1)
    if c.box_m is not None or c.tracker_m is not None or c.keep_out_m:
        p, n = reflector_pose(robot, q, c)
        if c.box_m is not None:
            ok &= np.all((p >= c.box_m[0]) & (p <= c.box_m[1]), axis=1)
        for b in c.keep_out_m:
            ok &= ~np.all((p >= b[0]) & (p <= b[1]), axis=1)
        if c.tracker_m is not None:
            ok &= incidence_deg(p, n, c.tracker_m) <= c.max_incidence_deg
            ok &= np.linalg.norm(p - c.tracker_m, axis=1) >= c.min_range_m
            for b in c.keep_out_m:
                ok &= ~segment_hits_box(np.broadcast_to(c.tracker_m, p.shape), p, b)
    rows = np.flatnonzero(ok)  # the body test, the costliest, only where everything else holds
    if c.bodies is not None and rows.size:
        ok[rows] = body_clear(robot, q[rows], c.bodies, c.floor_z_m, c.keep_out_m,
                              points_m=() if c.tracker_m is None else (c.tracker_m,))
    elif c.floor_z_m is not None and rows.size:  # no body model: at least the TCP stays above the floor
        ok[rows] = fk(robot, q[rows])[:, 2, 3] >= c.floor_z_m
    return ok


def parse_box(text: str, what: str = "box", length_unit: str = "m") -> np.ndarray:
    """``"xmin,ymin,zmin,xmax,ymax,zmax"`` -> ``(2, 3)`` m (``length_unit`` m or mm)."""
    try:
        v = np.array([float(x) for x in str(text).replace(";", ",").split(",")])
    except ValueError:
        raise PlanningError(f"{what}: expected 6 numbers xmin,ymin,zmin,xmax,ymax,zmax, got {text!r}") from None
    if v.size != 6:
        raise PlanningError(f"{what}: expected 6 numbers xmin,ymin,zmin,xmax,ymax,zmax, got {v.size} in {text!r}")
    return _box(v * _length_factor(length_unit), what)


def _length_factor(unit: str) -> float:
    if unit not in ("m", "mm"):
        raise PlanningError(f"length unit must be m or mm, got {unit!r}")
    return 1e-3 if unit == "mm" else 1.0


def parse_region(robot: Robot, text: str, angle_unit: str = "deg") -> tuple[np.ndarray, np.ndarray]:
    """``"lo1:hi1,lo2:hi2,..."`` (one range per joint; ``:`` alone keeps the limits) -> ``(lower, upper)``.

    Revolute ranges in ``angle_unit`` (deg or rad), prismatic in m."""
    if angle_unit not in ("deg", "rad"):
        raise PlanningError(f"angle unit must be deg or rad, got {angle_unit!r}")
    parts = [s.strip() for s in str(text).split(",")]
    if len(parts) != robot.dof:
        raise PlanningError(f"region: expected {robot.dof} comma-separated ranges lo:hi (one per joint), got {len(parts)}")
    lo, hi = robot.lower.copy(), robot.upper.copy()
    for j, s in enumerate(parts):
        if ":" not in s:
            raise PlanningError(f"region: joint {j + 1}: expected lo:hi, got {s!r}")
        a, b = s.split(":", 1)
        f = np.pi / 180 if angle_unit == "deg" and robot.independent_joint_type[j] == "revolute" else 1.0
        try:
            if a.strip():
                lo[j] = float(a) * f
            if b.strip():
                hi[j] = float(b) * f
        except ValueError:
            raise PlanningError(f"region: joint {j + 1}: not a number in {s!r}") from None
    return region_bounds(robot, lo, hi, angle_unit)
