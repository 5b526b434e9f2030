"""Referencing: express tracker measurements in the robot's frames (DESIGN.md §1.4).

Frames from joint sweeps (float64, metres and radians), with first-order uncertainty:

* :func:`base_frame_from_sweeps` / :func:`tool_frame_from_sweeps` — the robot's DH base frame from
  joint 1 and 2 sweeps; the flange frame from joint 5 and 6 sweeps.
* :func:`frame_from_axes` — a DH link frame from two consecutive joint axes.

The geometry fits they rest on (:func:`~hykin.measure.fits.fit_plane`,
:func:`~hykin.measure.fits.fit_circle_3d`, :func:`~hykin.measure.fits.axis_from_sweep`) live in
:mod:`hykin.measure.fits`.

The rigid registration of point sets (:func:`~hykin.geometry.rigid.kabsch`,
:func:`~hykin.geometry.rigid.register_points`, :func:`~hykin.geometry.rigid.pose_from_three_points`)
lives in :mod:`hykin.geometry.rigid`.

The covariances of the frames are propagated from the axis (and plane) fits' covariances with a
numerical Jacobian.

Degenerate input (too few points, collinear points, parallel axes) raises :class:`ReferencingError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.lsq import ReferencingError, as_points
from ..geometry.se3 import make_transform, matrix_to_rotvec
from .fits import AxisFit, axis_from_sweep, fit_plane

__all__ = [
    "Frame",
    "ReferencingError",
    "base_frame_from_sweeps",
    "frame_from_axes",
    "tool_frame_from_sweeps",
]


# --------------------------------------------------------------------------- frames


@dataclass(frozen=True)
class Frame:
    """A measured frame: ``T`` ``(4, 4)`` maps frame coordinates to tracker coordinates (m).

    cov: ``(6, 6)`` covariance of ``(δp (m), δθ (rad))`` with ``T_true ≈ [exp(δθ) R, p + δp]``, both in
    tracker coordinates; std_pos_m ``(3,)`` and std_rot_rad ``(3,)`` are the roots of its diagonal.
    axes: the :class:`AxisFit` objects used; info: how the frame was built.
    """

    T: np.ndarray
    cov: np.ndarray
    std_pos_m: np.ndarray
    std_rot_rad: np.ndarray
    axes: tuple = ()
    info: dict = field(default_factory=dict)

    @property
    def pos_std_m(self) -> float:
        """RMS 3-D position uncertainty (m)."""
        return float(np.sqrt(np.trace(self.cov[:3, :3])))

    @property
    def rot_std_rad(self) -> float:
        """RMS rotation uncertainty (rad)."""
        return float(np.sqrt(np.trace(self.cov[3:, 3:])))


def _common_perpendicular(pa, za, pb, zb, name):
    """Feet ``fa`` on line a and ``fb`` on line b of the common perpendicular."""
    b = za @ zb
    denom = 1.0 - b * b
    if denom < 1e-12:
        raise ReferencingError(f"{name}: the two axes are parallel; their common perpendicular is not unique")
    w0 = pa - pb
    d, e = za @ w0, zb @ w0
    sa = (b * e - d) / denom
    tb = (e - b * d) / denom
    return pa + sa * za, pb + tb * zb


def _rz(v, z, ang):
    """Rotate vector v about unit z by ang (Rodrigues)."""
    c, s = np.cos(ang), np.sin(ang)
    return v * c + np.cross(z, v) * s + z * (z @ v) * (1 - c)


def frame_from_axes(pa, za, pb, zb, *, at: str = "a", a_sign: float = 1.0, alpha_rad: float | None = None,
                    min_offset_m: float = 1e-3, name: str = "frame_from_axes") -> np.ndarray:
    """DH link frame ``(4, 4)`` built from two consecutive joint axes a (earlier) and b (later).

    ``x`` lies along the common perpendicular, pointing from axis a to axis b (times ``a_sign``, the
    sign of the DH ``a`` between them). When the axes intersect (distance < ``min_offset_m``) the
    common perpendicular has no direction and DH puts ``x = sign(sin alpha) (z_a × z_b)``: then
    ``alpha_rad`` (DH twist between the axes) is required. ``at="a"``: ``z = z_a``, origin at the
    foot on axis a (the DH frame *before* the link, at joint angle 0 after removing the rotation,
    see callers); ``at="b"``: ``z = z_b``, origin at the foot on axis b (DH frame after the link).
    """
    za = za / np.linalg.norm(za)
    zb = zb / np.linalg.norm(zb)
    fa, fb = _common_perpendicular(pa, za, pb, zb, name)
    dvec = fb - fa
    dist = np.linalg.norm(dvec)
    if dist >= min_offset_m:
        x = a_sign * dvec / dist
    else:
        if alpha_rad is None:
            raise ReferencingError(
                f"{name}: the axes intersect (distance {dist * 1e3:.3g} mm < {min_offset_m * 1e3:g} mm), so the "
                "x direction comes from the DH twist: pass alpha_rad (or robot=)")
        sgn = np.sign(np.sin(alpha_rad))
        if sgn == 0:
            raise ReferencingError(f"{name}: alpha_rad={alpha_rad} gives parallel axes, but the axes are not parallel")
        x = sgn * np.cross(za, zb)
        x /= np.linalg.norm(x)
    z = za if at == "a" else zb
    o = fa if at == "a" else fb
    x = x - z * (z @ x)
    x /= np.linalg.norm(x)
    return make_transform(np.stack([x, np.cross(z, x), z], axis=1), o)


def _tilted(axis: AxisFit, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis point and direction with perturbation params (dc (3), tilt_u, tilt_v)."""
    u, v = axis.circle.basis
    m = axis.direction + params[3] * u + params[4] * v
    return axis.point + params[:3], m / np.linalg.norm(m)


def _propagate(build, axes: list[AxisFit], extra_cov: np.ndarray | None = None, n_extra: int = 0,
               h: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """Evaluate ``build(perturbation)`` and propagate the axes' (and extra) covariances to the frame."""
    k = 5 * len(axes) + n_extra
    C = np.zeros((k, k))
    for i, ax in enumerate(axes):
        C[5 * i : 5 * i + 5, 5 * i : 5 * i + 5] = ax.circle.cov[:5, :5]
    if n_extra:
        C[k - n_extra :, k - n_extra :] = extra_cov
    T0 = build(np.zeros(k))
    J = np.zeros((6, k))
    for j in range(k):
        dx = np.zeros(k)
        dx[j] = h
        Tp, Tm = build(dx), build(-dx)
        J[:3, j] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        J[3:, j] = (matrix_to_rotvec(Tp[:3, :3] @ T0[:3, :3].T) - matrix_to_rotvec(Tm[:3, :3] @ T0[:3, :3].T)) / (2 * h)
    return T0, J @ C @ J.T


def _frame(T, cov, axes, info) -> Frame:
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    return Frame(T=T, cov=cov, std_pos_m=d[:3], std_rot_rad=d[3:], axes=tuple(axes), info=info)


def _dh_from_robot(robot, i: int):
    if robot is None:
        return None
    if robot.convention != "dh":
        raise ReferencingError(f"robot {robot.name!r}: sweep referencing uses standard DH parameters, "
                               f"got convention {robot.convention!r} (convert with hykin.kinematics.robot.mdh_to_dh)")
    return dict(a=float(robot.a_m[i]), alpha=float(robot.alpha_rad[i]), d=float(robot.d_m[i]),
                theta=float(robot.theta_rad[i]), beta=float(robot.beta_rad[i]))


def _sign_of(a_from_robot, explicit) -> float:
    val = explicit if explicit is not None else a_from_robot
    if val is None or float(val) == 0.0:
        return 1.0
    return float(np.sign(val))


def base_frame_from_sweeps(j1_points, j2_points, *, robot=None, q1_rad: float = 0.0, d1_m: float | None = None,
                           alpha1_rad: float | None = None, a1_sign: float | None = None,
                           theta1_rad: float | None = None, base_plane_points=None,
                           min_offset_m: float = 1e-3) -> Frame:
    """Robot base frame (standard DH frame 0) in tracker coordinates from joint 1 and 2 sweeps.

    ``j1_points``: SMR positions ``(N1, 3)`` while joint 1 alone turns; ``j2_points`` ``(N2, 3)`` while
    joint 2 alone turns with joint 1 at ``q1_rad``. Both in increasing joint angle (this fixes the
    signs of the axes: ``z`` = positive rotation axis of joint 1).

    * ``z`` = axis 1.
    * origin = where axis 1 meets the *base plane*. By default the base plane is the plane normal to
      axis 1 at a distance ``d1_m`` below the foot of the common perpendicular of axes 1 and 2 (the
      shoulder height): with the DH ``d1`` of the robot this is exactly DH frame 0. With
      ``base_plane_points`` (SMR positions measured on the mounting surface) the base plane is the
      plane fitted to them instead and ``d1_m`` is ignored.
    * ``x`` = direction of the common perpendicular from axis 1 to axis 2 (times ``a1_sign``), turned
      back about ``z`` by ``theta1_rad + q1_rad`` so that it is DH ``x0``. If axes 1 and 2 intersect
      (e.g. UR arms), ``x = sign(sin alpha1) · (z1 × z2)`` — DH's choice — and ``alpha1_rad`` is needed.

    ``robot`` (standard DH) supplies ``d1_m``, ``alpha1_rad``, ``a1_sign`` and ``theta1_rad`` unless
    given explicitly; otherwise ``d1_m = 0``, ``a1_sign = +1``, ``theta1_rad = 0``. Assumes ``beta1 = 0``.
    The returned :class:`Frame` is the robot base pose in the tracker frame, i.e. ``Robot.base`` when
    the world frame is the tracker frame.
    """
    dh = _dh_from_robot(robot, 0) or {}
    d1 = dh.get("d", 0.0) if d1_m is None else float(d1_m)
    alpha = dh.get("alpha") if alpha1_rad is None else float(alpha1_rad)
    asg = _sign_of(dh.get("a"), a1_sign)
    th = dh.get("theta", 0.0) if theta1_rad is None else float(theta1_rad)
    ax1 = axis_from_sweep(as_points(j1_points, "base_frame_from_sweeps: j1_points", 4))
    ax2 = axis_from_sweep(as_points(j2_points, "base_frame_from_sweeps: j2_points", 4))
    plane = fit_plane(base_plane_points) if base_plane_points is not None else None

    def build(x):
        pa, za = _tilted(ax1, x[:5])
        pb, zb = _tilted(ax2, x[5:10])
        F = frame_from_axes(pa, za, pb, zb, at="a", a_sign=asg, alpha_rad=alpha, min_offset_m=min_offset_m,
                            name="base_frame_from_sweeps")
        z = F[:3, 2]
        xdir = _rz(F[:3, 0], z, -(th + q1_rad))
        if plane is None:
            o = F[:3, 3] - d1 * z
        else:
            u, v = plane.basis
            m = plane.normal + x[10] * u + x[11] * v
            n = m / np.linalg.norm(m)
            p0 = plane.point + x[12] * plane.normal
            den = n @ z
            if abs(den) < 1e-6:
                raise ReferencingError("base_frame_from_sweeps: base plane is parallel to axis 1")
            o = pa + ((n @ (p0 - pa)) / den) * za
        return make_transform(np.stack([xdir, np.cross(z, xdir), z], axis=1), o)

    extra = None if plane is None else plane.cov
    T, cov = _propagate(build, [ax1, ax2], extra, 0 if plane is None else 3)
    info = dict(d1_m=d1, q1_rad=q1_rad, theta1_rad=th, a1_sign=asg, alpha1_rad=alpha,
                axis_distance_m=float(np.linalg.norm(np.subtract(*_common_perpendicular(
                    ax1.point, ax1.direction, ax2.point, ax2.direction, "base")))),
                base_plane="fitted" if plane is not None else f"normal to axis 1, {d1} m below the shoulder")
    return _frame(T, cov, [ax1, ax2], info)


def tool_frame_from_sweeps(j5_points, j6_points, *, robot=None, q6_rad: float = 0.0, d6_m: float | None = None,
                           a6_m: float | None = None, alpha6_rad: float | None = None,
                           theta6_rad: float | None = None, alpha5_rad: float | None = None,
                           a5_sign: float | None = None, min_offset_m: float = 1e-3) -> Frame:
    """Flange frame (standard DH frame 6) in tracker coordinates from joint 5 and 6 sweeps.

    ``j5_points`` ``(N5, 3)``: SMR on the tool while joint 5 alone turns; ``j6_points`` ``(N6, 3)``:
    while joint 6 alone turns, with joint 5 where the frame is wanted (axis 6 moves with joint 5,
    axis 5 does not). Both in increasing joint angle.

    DH frame 5: ``z`` = axis 6, origin = foot on axis 6 of the common perpendicular with axis 5 (the
    wrist centre for a spherical wrist), ``x`` from axis 5 toward axis 6 (times ``a5_sign``) or, when
    they intersect, ``sign(sin alpha5) · (z5 × z6)``. The flange is then
    ``frame5 · Rz(theta6 + q6) · Tz(d6) · Tx(a6) · Rx(alpha6)`` with ``q6_rad`` the joint-6 angle at
    which the flange pose is wanted. ``robot`` (standard DH) supplies the DH values not given;
    without it ``d6 = a6 = alpha6 = theta6 = 0`` and ``a5_sign = +1``.
    Use it with a measured SMR position ``p`` to get the TCP in flange coordinates:
    ``inv(frame.T) @ [p, 1]``.
    """
    dh5 = _dh_from_robot(robot, 4) or {}
    dh6 = _dh_from_robot(robot, 5) or {}
    alpha5 = dh5.get("alpha") if alpha5_rad is None else float(alpha5_rad)
    asg = _sign_of(dh5.get("a"), a5_sign)
    d6 = dh6.get("d", 0.0) if d6_m is None else float(d6_m)
    a6 = dh6.get("a", 0.0) if a6_m is None else float(a6_m)
    al6 = dh6.get("alpha", 0.0) if alpha6_rad is None else float(alpha6_rad)
    th6 = dh6.get("theta", 0.0) if theta6_rad is None else float(theta6_rad)
    ax5 = axis_from_sweep(as_points(j5_points, "tool_frame_from_sweeps: j5_points", 4))
    ax6 = axis_from_sweep(as_points(j6_points, "tool_frame_from_sweeps: j6_points", 4))
    c6, s6 = np.cos(th6 + q6_rad), np.sin(th6 + q6_rad)
    ca, sa = np.cos(al6), np.sin(al6)
    L = np.array([[c6, -s6 * ca, s6 * sa, a6 * c6], [s6, c6 * ca, -c6 * sa, a6 * s6],
                  [0, sa, ca, d6], [0, 0, 0, 1.0]])

    def build(x):
        pa, za = _tilted(ax5, x[:5])
        pb, zb = _tilted(ax6, x[5:10])
        F5 = frame_from_axes(pa, za, pb, zb, at="b", a_sign=asg, alpha_rad=alpha5, min_offset_m=min_offset_m,
                             name="tool_frame_from_sweeps")
        return F5 @ L

    T, cov = _propagate(build, [ax5, ax6])
    info = dict(q6_rad=q6_rad, d6_m=d6, a6_m=a6, alpha6_rad=al6, theta6_rad=th6, alpha5_rad=alpha5, a5_sign=asg)
    return _frame(T, cov, [ax5, ax6], info)
