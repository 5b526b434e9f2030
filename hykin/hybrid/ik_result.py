"""Hybrid IK result type, errors and the input checks shared by the hybrid IK modules.

Units: joints rad (m for prismatic), positions m, reported errors mm and degrees.
"""

from __future__ import annotations

import contextlib
import sys
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3
from ..io.modelfile import model_metrics
from ..kinematics.robot import Robot

__all__ = [
    "DEFAULT_DELTA_RAD", "ROW_FIELDS", "HybridIKError", "HybridIKResult", "check_model", "classical_robot",
    "model_accuracy", "model_metrics", "model_tcp_shift", "parse_targets", "predict_quiet", "support_of", "torch_threads",
    "underactuated",
]

DEFAULT_DELTA_RAD = float(np.radians(3.0))


class HybridIKError(ValueError):
    """Bad input to hybrid IK (shapes, non-finite targets, a model without the needed methods)."""


@dataclass
class HybridIKResult:
    """One row per solution (or per failed target), flattened over targets × branches.

    target: ``(M,)`` int, row index of the target in the input.
    branch: ``(M,)`` str, branch label (e.g. shoulder/elbow/wrist ``"LUF"``; ``"seed"`` for user seeds).
    q: ``(M, dof)`` joints (rad / m); NaN where no joints exist (no classical solution at all).
    success: ``(M,)`` bool, error within ``success_mm`` / ``success_deg`` and inside joint limits.
    pos_err_mm, ang_err_deg: ``(M,)`` achieved error of the hybrid pose ``T*(q)`` to the target (NaN
        when there are no joints; ``ang_err_deg`` is 0 for position-only targets).
    reason: ``(M,)`` str, ``""`` on success, otherwise why it failed.
    in_support: ``(M,)`` bool, joints inside the model's training support (True when the model has
        no ``support_distance``).
    support_distance: ``(M,)`` float, ``model.support_distance(q)`` (0 inside; NaN when unknown).
    iterations: ``(M,)`` int, solver iterations used.
    n_targets: number of input targets; position_only: whether orientation was ignored.
    """

    target: np.ndarray
    branch: np.ndarray
    q: np.ndarray
    success: np.ndarray
    pos_err_mm: np.ndarray
    ang_err_deg: np.ndarray
    reason: np.ndarray
    in_support: np.ndarray
    support_distance: np.ndarray
    iterations: np.ndarray
    n_targets: int
    position_only: bool = False
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.target.shape[0])

    @property
    def solved_targets(self) -> np.ndarray:
        """``(n_targets,)`` bool: the target has at least one successful solution."""
        out = np.zeros(self.n_targets, dtype=bool)
        out[self.target[self.success]] = True
        return out

    def select(self, mask: np.ndarray) -> HybridIKResult:
        """Rows where ``mask`` (bool ``(M,)`` or index array) is set."""
        kw = {k: getattr(self, k)[mask] for k in ROW_FIELDS}
        return HybridIKResult(**kw, n_targets=self.n_targets, position_only=self.position_only, info=dict(self.info))


ROW_FIELDS = (
    "target", "branch", "q", "success", "pos_err_mm", "ang_err_deg", "reason", "in_support",
    "support_distance", "iterations",
)


# --------------------------------------------------------------------------- inputs


def model_accuracy(model) -> tuple[float | None, float | None]:
    """``(mm, deg)``: how far the model's own poses are from measured ones: its held-out maximum hybrid
    position / orientation error, else 3 × the mean (:func:`model_metrics`); None where unknown.

    The tolerance of the part of a pose an under-actuated arm cannot control (:func:`underactuated`):
    a measured target differs from the model's pose by the model's error, and its uncontrollable part
    is never larger, so an arm that misses a target by less than the model misses measured poses
    reaches it as well as the model can tell."""
    src = model_metrics(model)
    out = []
    for kind, unit in (("pos", "mm"), ("rot", "deg")):
        mx, mean = src.get(f"hybrid_{kind}_max_{unit}"), src.get(f"hybrid_{kind}_mean_{unit}")
        v = mx if mx is not None and np.isfinite(mx) else (3.0 * mean if mean is not None and np.isfinite(mean) else None)
        out.append(None if v is None else float(v))
    return out[0], out[1]


def underactuated(robot: Robot, position_only: bool) -> bool:
    """Fewer joints than the IK residual has components (< 6 for poses, < 3 for positions): an arbitrary
    (measured) target has no exact solution, only a least-squares one."""
    return robot.dof < (3 if position_only else 6)


def classical_robot(model) -> Robot:
    """The model's calibrated classical robot: ``model.robot_`` (a fitted :class:`hykin.hybrid.model.HybridModel`,
    whose ``robot`` is the nominal one) or else ``model.robot``."""
    for name in ("robot_", "robot"):
        r = getattr(model, name, None)
        if isinstance(r, Robot):
            return r
    raise HybridIKError("hybrid IK: the model must have a classical robot (`model.robot_` or `model.robot`)")


def model_tcp_shift(model) -> np.ndarray:
    """``(4, 4)``: the model's TCP (its calibrated tool, with a registration's ``frame_post_``) relative to
    its robot file's TCP. Where a program's tool fixed to the real flange sits (compensation), how far the
    file's tool is from what was measured (the CLI's warning, the evaluation's frame test)."""
    post = np.asarray(getattr(model, "frame_post_", np.eye(4)), dtype=np.float64)
    return se3.invert(np.asarray(model.nominal.tool)) @ np.asarray(classical_robot(model).tool) @ post


def predicting_robot(model) -> Robot:
    """:func:`classical_robot` in the frames the model's ``predict`` answers in: a registered model's
    fitted frames (``frame_pre_`` · T · ``frame_post_``: a moved tracker, a new tool) folded into its base
    and tool, so that its classical FK (and closed form) seeds and linearises targets given in that frame."""
    robot = classical_robot(model)
    pre, post = getattr(model, "frame_pre_", None), getattr(model, "frame_post_", None)
    if pre is None or post is None or (np.array_equal(pre, np.eye(4)) and np.array_equal(post, np.eye(4))):
        return robot
    return robot.copy(base=np.asarray(pre, dtype=np.float64) @ robot.base, tool=robot.tool @ np.asarray(post, dtype=np.float64))


def check_model(model) -> Robot:
    """The model's classical robot as its ``predict`` places it (:func:`predicting_robot`); HybridIKError
    for a model without ``predict``."""
    robot = predicting_robot(model)
    if not callable(getattr(model, "predict", None)):
        raise HybridIKError("hybrid IK: the model must have `predict(q)` -> (N, 4, 4) poses")
    return robot


def parse_targets(T_target) -> tuple[np.ndarray, bool]:
    """Targets as ``(N, 4, 4)`` (positions get an identity rotation) and the position-only flag."""
    T = np.asarray(T_target, dtype=np.float64)
    if T.ndim == 1 and T.shape[0] == 3 or T.shape == (4, 4):
        T = T[None]
    if T.ndim == 2 and T.shape[1] == 3:
        pos_only = True
        T = se3.make_transform(np.broadcast_to(np.eye(3), (T.shape[0], 3, 3)), T)
    elif T.ndim == 3 and T.shape[1:] == (4, 4):
        pos_only = False
    else:
        raise HybridIKError(f"hybrid IK: targets must be (N, 4, 4) poses or (N, 3) positions, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        bad = int(np.argmax(~np.all(np.isfinite(T.reshape(T.shape[0], -1)), axis=1)))
        raise HybridIKError(f"hybrid IK: target row {bad} is not finite")
    if not pos_only:
        R = T[:, :3, :3]
        dev = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
        if np.any(dev > 1e-6):
            bad = int(np.argmax(dev > 1e-6))
            raise HybridIKError(f"hybrid IK: target row {bad} has a non-orthonormal rotation (|RRᵀ-I| = {dev[bad]:.2e})")
    return T, pos_only

@contextlib.contextmanager
def torch_threads(n: int | None):
    """Run with ``n`` torch intra-op threads (restored afterwards); no-op for None or without torch.

    The solver evaluates the networks on modest batches many times: one thread is as fast on an idle
    machine and several times faster on a busy one (no spinning worker threads)."""
    torch = sys.modules.get("torch")
    if n is None or torch is None:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def support_of(model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fn = getattr(model, "support_distance", None)
    dist = np.full(q.shape[0], np.nan)
    finite = np.all(np.isfinite(q), axis=1)
    if fn is None or not finite.any():
        return dist, np.ones(q.shape[0], dtype=bool)
    dist[finite] = np.asarray(fn(q[finite]), dtype=np.float64).reshape(-1)
    return dist, ~(dist > 0)


def predict_quiet(model, q: np.ndarray) -> np.ndarray:
    with warnings.catch_warnings(), torch_threads(1):
        warnings.simplefilter("ignore")
        return np.asarray(model.predict(q), dtype=np.float64).reshape(-1, 4, 4)

