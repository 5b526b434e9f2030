"""Checks of targets read from a file before they are compensated: quaternions in the wrong order.

A CSV whose quaternions are written scalar-last (x, y, z, w) under a ``qw,qx,qy,qz`` header reads as other
orientations; many are still reachable, and those were compensated at the wrong orientation, exit 0 (probe
s42 AQ: 27 of 40 "compensated" up to 179.8° off; the other 13 refused, blaming joint limits). Evidence for
the other order, each a refusal only where it is clear:

* with joints per target (``q1..qN``): the relative rotations of the targets against the nominal robot's
  at those joints (:func:`hykin.io.plausibility.check_orientation_order`, the measured-data check), fitting
  clearly better read scalar-last; or the targets' rotations near the model's own at those joints read
  scalar-last and far from them as written (a path of little rotation, where the relative test cannot tell);
* always: the calibrated robot reaching clearly more of the targets read scalar-last than as written (at
  least :data:`MIN_UNREACHED` and a tenth of the rows out of reach as written, at most a quarter of those
  read the other way). Only where the targets' orientations vary (median pairwise angle at least
  :data:`MIN_SPREAD_DEG`): a slip scrambles varied orientations, while a file of one orientation the arm
  cannot take at some places is as likely (probe s42 AV: 12 of 30 targets at one orientation out of reach,
  all reachable at the swapped one: a correct file was refused); there it is a warning.

``hykin compensate --quaternion-order wxyz|xyzw`` says the order, and then nothing is checked.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..geometry import se3

__all__ = ["MIN_UNREACHED", "check_quaternion_order"]

MIN_UNREACHED = 3
MIN_SPREAD_DEG = 30.0
NEAR_DEG, FAR_DEG = 10.0, 30.0  # the model's rotation at given joints: a reading this near, the other this far
_SAMPLE = 300  # rows the reach test solves (spread over the file)


def _reached(robot, T: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: the (calibrated) robot reaches the TCP poses ``T`` (its world) within its limits."""
    from ..kinematics.ik import ik

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(ik(robot, T, all_branches=True).success, dtype=bool).reshape(len(T), -1).any(1)


def _spread_deg(R: np.ndarray) -> float:
    """Median angle (deg) between the rotations ``R`` ``(M, 3, 3)`` pairwise (at most 60 of them)."""
    R = R[np.unique(np.linspace(0, len(R) - 1, min(len(R), 60)).round().astype(int))]
    i, j = np.triu_indices(len(R), 1)
    if not i.size:
        return 0.0
    return float(np.degrees(np.median(np.linalg.norm(se3.matrix_to_rotvec(R[i] @ np.swapaxes(R[j], -1, -2)), axis=1))))


def _check_against_joints(model, T: np.ndarray, swapped: np.ndarray, frame: str, q, D, where: str) -> None:
    """ValueError where the targets' rotations, read scalar-last, lie near the model's at the given joints
    (median within :data:`NEAR_DEG`) and as written far from them (at least :data:`FAR_DEG` and 4 times as far).
    The relative test cannot tell a path of little rotation (stop 42's own run: a 60-target path, joints given,
    10 targets compensated at orientations 120° off with a warning only); the model's rotation at those joints
    can, in its own frame. Joints that only hint at a branch fit neither reading: nothing is said."""
    from .frames import to_model_frame
    from .tool_shift import model_delta

    Dm = None if D is None else model_delta(model, np.broadcast_to(np.asarray(D, dtype=np.float64), T.shape))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (joints outside the training support: the rotation is still the model's)
        R = np.asarray(model.predict(np.asarray(q, dtype=np.float64)), dtype=np.float64)[:, :3, :3]

    def median_deg(Tx):
        Tm = to_model_frame(model, Tx, frame)
        Rt = (Tm if Dm is None else Tm @ se3.invert(Dm))[:, :3, :3]
        return float(np.degrees(np.median(np.linalg.norm(se3.matrix_to_rotvec(Rt @ np.swapaxes(R, -1, -2)), axis=1))))

    written, other = median_deg(T), median_deg(swapped)
    if other <= NEAR_DEG and written >= max(FAR_DEG, 4 * other):
        raise ValueError(f"{where}: the targets' orientations lie {written:.3g}° (median) from the model's at their "
                         f"joints as written (qw,qx,qy,qz), {other:.3g}° read as x,y,z,w: the quaternions look "
                         "scalar-last (x,y,z,w) under a qw,qx,qy,qz header; reorder the columns (--quaternion-order "
                         "xyzw reads them so; wxyz says they are as written)")


def check_quaternion_order(model, T: np.ndarray, frame: str, q=None, D=None, where: str = "<targets>") -> str:
    """ValueError naming ``where`` and the likely cause when the targets ``T`` ``(N, 4, 4)`` (m, in ``frame``,
    rotations from quaternions read scalar-first; ``D``: their TCP relative to the robot file's, or None)
    look like scalar-last quaternions (module docstring); ``q`` ``(N, n)``: joints given per target. Returns
    a warning where the evidence is weak (little variety of orientation), else ``""``."""
    from ..hybrid.ik_result import classical_robot
    from ..io.plausibility import PlausibilityError, check_orientation_order
    from .frames import to_model_frame
    from .tool_shift import model_delta

    T = np.asarray(T, dtype=np.float64)
    quat = se3.matrix_to_quat(T[:, :3, :3])
    swapped = T.copy()
    swapped[:, :3, :3] = se3.quat_to_matrix(quat[:, [3, 0, 1, 2]])
    if q is not None:
        try:
            check_orientation_order(model.nominal, q, quat, where=where, order_only=True)
        except PlausibilityError as e:
            raise ValueError(f"{e} (if they are scalar-first as the header says: --quaternion-order wxyz)") from None
        _check_against_joints(model, T, swapped, frame, q, D, where)
    idx = np.unique(np.linspace(0, len(T) - 1, min(len(T), _SAMPLE)).round().astype(int))
    Dm = None if D is None else model_delta(model, np.broadcast_to(np.asarray(D, dtype=np.float64), T.shape)[idx])
    post_inv = se3.invert(np.asarray(model.frame_post_, dtype=np.float64))
    pre_inv = se3.invert(np.asarray(model.frame_pre_, dtype=np.float64))

    def robot_world(Tx):
        Tm = to_model_frame(model, Tx[idx], frame)
        return pre_inv @ (Tm if Dm is None else Tm @ se3.invert(Dm)) @ post_inv

    robot = classical_robot(model)
    given = int((~_reached(robot, robot_world(T))).sum())
    if given < max(MIN_UNREACHED, 0.1 * len(idx)):
        return ""
    other = int((~_reached(robot, robot_world(swapped))).sum())
    if other > 0.25 * given:
        return ""
    text = (f"{where}: {given} of {len(idx)} targets are out of the robot's reach with the quaternions as written "
            f"(qw,qx,qy,qz), {other} read as x,y,z,w: the quaternions look scalar-last (x,y,z,w) under a qw,qx,qy,qz "
            "header; reorder the columns (--quaternion-order xyzw reads them so; wxyz says they are as written)")
    spread = _spread_deg(T[idx, :3, :3])
    if spread < MIN_SPREAD_DEG:  # one orientation, or nearly: reach at another one is weak evidence
        return f"{text}. Not refused: the targets' orientations vary by {spread:.3g}° only"
    raise ValueError(text)
