"""SE(3) and SO(3) utilities, batched over leading dimensions.

Conventions (used everywhere in hykin):

* Homogeneous transforms are ``(..., 4, 4)`` float64 arrays, translation in metres.
* Quaternions are scalar-first ``(..., 4)`` = ``(qw, qx, qy, qz)`` (the dataset column order).
* Rotation vectors are ``(..., 3)`` = axis * angle in radians.
* RPY is roll, pitch, yaw about the *fixed* x, y, z axes (URDF): ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

numpy functions first; the ``*_torch`` functions at the end are differentiable twins used by the
hybrid model and by calibration.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "compose",
    "ikpy_metric",
    "invert",
    "make_transform",
    "matrix_to_quat",
    "matrix_to_rotvec",
    "matrix_to_rpy",
    "pose_error",
    "pose_to_transform",
    "quat_to_matrix",
    "rotation_difference_rotvec",
    "rotvec_to_matrix",
    "rotx",
    "roty",
    "rotz",
    "rpy_to_matrix",
    "so3_exp_torch",
    "so3_log_torch",
    "trans",
    "transform_to_pose",
    "transform_to_xyzrpy",
    "xyzrpy_to_transform",
]


def _flat(x: np.ndarray, tail: tuple[int, ...]) -> tuple[np.ndarray, tuple[int, ...]]:
    x = np.asarray(x, dtype=np.float64)
    lead = x.shape[: x.ndim - len(tail)]
    return x.reshape((-1,) + tail), lead


def make_transform(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Build ``(..., 4, 4)`` transforms from rotations ``(..., 3, 3)`` and positions ``(..., 3)``."""
    R = np.asarray(R, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    lead = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(lead + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)`` using ``R^T``, exact for orthonormal R."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def compose(*Ts: np.ndarray) -> np.ndarray:
    """Product ``T1 @ T2 @ ...`` with broadcasting over leading dimensions."""
    out = np.asarray(Ts[0], dtype=np.float64)
    for T in Ts[1:]:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def _axis_rot(angle, axis: int) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    T = np.zeros(angle.shape + (4, 4))
    T[..., 3, 3] = 1.0
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    T[..., axis, axis] = 1.0
    T[..., i, i] = c
    T[..., j, j] = c
    T[..., i, j] = -s
    T[..., j, i] = s
    return T


def rotx(angle_rad) -> np.ndarray:
    """Homogeneous rotation about x, ``(..., 4, 4)``."""
    return _axis_rot(angle_rad, 0)


def roty(angle_rad) -> np.ndarray:
    """Homogeneous rotation about y, ``(..., 4, 4)``."""
    return _axis_rot(angle_rad, 1)


def rotz(angle_rad) -> np.ndarray:
    """Homogeneous rotation about z, ``(..., 4, 4)``."""
    return _axis_rot(angle_rad, 2)


def trans(x_m=0.0, y_m=0.0, z_m=0.0) -> np.ndarray:
    """Homogeneous translation, broadcast over the arguments."""
    x, y, z = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (x_m, y_m, z_m)))
    T = np.zeros(x.shape + (4, 4))
    T[..., 0, 0] = T[..., 1, 1] = T[..., 2, 2] = T[..., 3, 3] = 1.0
    T[..., 0, 3], T[..., 1, 3], T[..., 2, 3] = x, y, z
    return T


def rotvec_to_matrix(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` to matrices ``(..., 3, 3)``."""
    r, lead = _flat(rotvec_rad, (3,))
    return Rotation.from_rotvec(r).as_matrix().reshape(lead + (3, 3))


# One rotation at a time (the real-time paths: a bridge cycle, a streamed target) in plain floats:
# scipy's Rotation costs ~100 us per call whatever the batch size. Same rules as scipy's (Shepperd's
# choice of the largest diagonal term, canonical qw >= 0, the rotation vector's small-angle series),
# so that a single rotation and the same one inside a batch agree to rounding; matrices that are not
# orthonormal within 1e-12 go to scipy (which projects them onto rotations first).

def _quat_one(m: list) -> tuple | None:
    """Row-major 3x3 ``m`` (9 floats) -> ``(w, x, y, z)`` with ``w >= 0``; None when not a rotation."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = m
    if not (abs(r00 * r00 + r01 * r01 + r02 * r02 - 1) < 1e-12 and abs(r10 * r10 + r11 * r11 + r12 * r12 - 1) < 1e-12
            and abs(r20 * r20 + r21 * r21 + r22 * r22 - 1) < 1e-12 and abs(r00 * r10 + r01 * r11 + r02 * r12) < 1e-12
            and abs(r00 * r20 + r01 * r21 + r02 * r22) < 1e-12 and abs(r10 * r20 + r11 * r21 + r12 * r22) < 1e-12):
        return None
    tr = r00 + r11 + r22
    big = max(r00, r11, r22, tr)  # the first of r00, r11, r22, tr that is largest (scipy's argmax)
    if big == r00:
        x, y, z, w = 1 - tr + 2 * r00, r10 + r01, r20 + r02, r21 - r12
    elif big == r11:
        x, y, z, w = r01 + r10, 1 - tr + 2 * r11, r21 + r12, r02 - r20
    elif big == r22:
        x, y, z, w = r02 + r20, r12 + r21, 1 - tr + 2 * r22, r10 - r01
    else:
        x, y, z, w = r21 - r12, r02 - r20, r10 - r01, 1 + tr
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if w < 0:
        n = -n
    return w / n, x / n, y / n, z / n


def _single(R) -> list | None:
    """The 9 floats of ``R`` when it holds exactly one ``(3, 3)`` matrix, else None."""
    R = np.asarray(R)
    return R.reshape(9).tolist() if R.size == 9 and R.shape[-2:] == (3, 3) and R.dtype.kind == "f" else None


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to rotation vectors ``(..., 3)`` (angle in [0, pi])."""
    m1 = _single(R)
    q = None if m1 is None else _quat_one(m1)
    if q is not None:
        w, x, y, z = q
        s = math.sqrt(x * x + y * y + z * z)
        angle = 2 * math.atan2(s, w)
        a2 = angle * angle
        scale = 2 + a2 / 12 + 7 * a2 * a2 / 2880 if angle <= 1e-3 else angle / math.sin(angle / 2)
        return np.array([scale * x, scale * y, scale * z]).reshape(np.shape(R)[:-2] + (3,))
    m, lead = _flat(R, (3, 3))
    return Rotation.from_matrix(m).as_rotvec().reshape(lead + (3,))


def quat_to_matrix(quat_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` scalar-first to matrices ``(..., 3, 3)``.

    The quaternion is normalised; callers that must reject non-unit input validate first
    (see :mod:`hykin.io.dataset`).
    """
    q, lead = _flat(quat_wxyz, (4,))
    if len(q) == 1:
        w, x, y, z = q[0].tolist()
        n = math.sqrt(w * w + x * x + y * y + z * z)
        if n > 0 and math.isfinite(n):
            w, x, y, z = w / n, x / n, y / n, z / n
            xx, yy, zz, ww = x * x, y * y, z * z, w * w
            xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
            return np.array([[xx - yy - zz + ww, 2 * (xy - zw), 2 * (xz + yw)],
                             [2 * (xy + zw), -xx + yy - zz + ww, 2 * (yz - xw)],
                             [2 * (xz - yw), 2 * (yz + xw), -xx - yy + zz + ww]]).reshape(lead + (3, 3))
    return Rotation.from_quat(q, scalar_first=True).as_matrix().reshape(lead + (3, 3))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Matrices ``(..., 3, 3)`` to scalar-first unit quaternions ``(..., 4)`` with ``qw >= 0``."""
    m1 = _single(R)
    q1 = None if m1 is None else _quat_one(m1)
    if q1 is not None:
        return np.array(q1).reshape(np.shape(R)[:-2] + (4,))
    m, lead = _flat(R, (3, 3))
    q = Rotation.from_matrix(m).as_quat(canonical=True, scalar_first=True)
    return q.reshape(lead + (4,))


def rpy_to_matrix(rpy_rad: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed x, y, z) ``(..., 3)`` to matrices ``(..., 3, 3)``."""
    r, lead = _flat(rpy_rad, (3,))
    return Rotation.from_euler("xyz", r).as_matrix().reshape(lead + (3, 3))


def matrix_to_rpy(R: np.ndarray) -> np.ndarray:
    """Matrices ``(..., 3, 3)`` to URDF roll-pitch-yaw ``(..., 3)`` in radians."""
    m, lead = _flat(R, (3, 3))
    import warnings

    with warnings.catch_warnings():
        # Gimbal lock is a legitimate input here; scipy still returns a valid triple.
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_matrix(m).as_euler("xyz")
    return rpy.reshape(lead + (3,))


def xyzrpy_to_transform(xyz_m, rpy_rad) -> np.ndarray:
    """Position ``(..., 3)`` and URDF RPY ``(..., 3)`` to transforms ``(..., 4, 4)``."""
    return make_transform(rpy_to_matrix(rpy_rad), xyz_m)


def transform_to_xyzrpy(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Transforms ``(..., 4, 4)`` to ``(xyz_m, rpy_rad)``."""
    T = np.asarray(T, dtype=np.float64)
    return T[..., :3, 3].copy(), matrix_to_rpy(T[..., :3, :3])


def pose_to_transform(xyz_m: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
    """Dataset pose columns (``x,y,z`` and ``qw,qx,qy,qz``) to ``(..., 4, 4)``."""
    return make_transform(quat_to_matrix(quat_wxyz), xyz_m)


def transform_to_pose(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Transforms ``(..., 4, 4)`` to ``(xyz_m (..., 3), quat_wxyz (..., 4))``."""
    T = np.asarray(T, dtype=np.float64)
    return T[..., :3, 3].copy(), matrix_to_quat(T[..., :3, :3])


def rotation_difference_rotvec(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """``log(R_a R_b^T)`` as rotation vectors ``(..., 3)``: the rotation taking b onto a, base frame."""
    D = np.asarray(R_a, dtype=np.float64) @ np.swapaxes(np.asarray(R_b, dtype=np.float64), -1, -2)
    return matrix_to_rotvec(D)


def pose_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error in **mm** and orientation error in **degrees** between two pose batches.

    Returns ``(pos_err_mm (...,), ang_err_deg (...,))``. The angle is that of ``R_a R_b^T``.
    """
    T_a = np.asarray(T_a, dtype=np.float64)
    T_b = np.asarray(T_b, dtype=np.float64)
    pos = np.linalg.norm(T_a[..., :3, 3] - T_b[..., :3, 3], axis=-1) * 1e3
    # Angle from the trace is inaccurate near 0; use the rotation vector norm instead.
    ang = np.linalg.norm(rotation_difference_rotvec(T_a[..., :3, :3], T_b[..., :3, :3]), axis=-1)
    return pos, np.degrees(ang)


def ikpy_metric(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """IKPy-style element-wise metric (DESIGN.md §1.3): sum of squared 4x4 differences, translation in mm."""
    A = np.array(T_a, dtype=np.float64, copy=True)
    B = np.array(T_b, dtype=np.float64, copy=True)
    A[..., :3, 3] *= 1e3
    B[..., :3, 3] *= 1e3
    return np.sum((A - B) ** 2, axis=(-1, -2))


# --------------------------------------------------------------------------- torch twins


def so3_exp_torch(rotvec):
    """Differentiable Rodrigues formula: rotation vectors ``(..., 3)`` to ``(..., 3, 3)``.

    Uses a Taylor expansion below 1e-4 rad so gradients stay finite at zero.
    """
    import torch

    theta2 = (rotvec * rotvec).sum(-1, keepdim=True)
    small = theta2 < 1e-8
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(theta2_safe)
    A = torch.where(small, 1 - theta2 / 6 + theta2 * theta2 / 120, torch.sin(theta) / theta)
    B = torch.where(small, 0.5 - theta2 / 24 + theta2 * theta2 / 720, (1 - torch.cos(theta)) / theta2_safe)
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(rotvec.shape[:-1] + (3, 3))
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(K)
    return eye + A[..., None] * K + B[..., None] * (K @ K)


def so3_log_torch(R):
    """Differentiable matrix log for rotations ``(..., 3, 3)`` -> rotation vectors ``(..., 3)``.

    Accurate for angles up to ~pi - 1e-3, which covers every residual this library takes the log of
    (residuals are small); near-pi angles fall back to a stable but non-differentiable formula.
    """
    import torch

    tr = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    cos = ((tr - 1) / 2).clamp(-1.0, 1.0)
    w = torch.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1
    )
    sin = 0.5 * torch.linalg.norm(w, dim=-1)
    theta = torch.atan2(sin, cos)
    small = theta < 1e-4
    sin_safe = torch.where(small, torch.ones_like(sin), sin)
    scale = torch.where(small, 0.5 + theta * theta / 12, theta / (2 * sin_safe))
    return w * scale[..., None]
