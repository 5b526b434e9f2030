"""Requests of ``hykin serve`` (:mod:`.service`): JSON in, checked arrays, the model call, JSON out.

Every endpoint has a ``parse_*`` method (checks only, no model: it runs on the server's event loop and
answers a bad request at once) and a method of the same name without the prefix (the model call: it
runs on the service's one model thread, :class:`hykin.compensation.service_guard.ModelWorker`).
Units: m, rad; poses as rows ``x, y, z, qw, qx, qy, qz``.

The service holds ONE warm compensator for its lifetime (:func:`warm_compensator`); streaming steps
go through :func:`step` and batches through the compensator's call.
"""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np

from ..geometry import se3
from .compensator import Compensator
from .targets import FRAMES, resolve_frame

__all__ = ["Handlers", "RequestError", "step", "warm_compensator"]


class RequestError(ValueError):
    """A request the service cannot answer: ``status`` (400/422) and a one-line reason."""

    def __init__(self, reason: str, status: int = 422):
        super().__init__(reason)
        self.status = status


class _Compensators:
    """The service's warm :class:`hykin.compensation.compensator.Compensator`: one for the default frame,
    built at start; one more for the other frame built on its first request and kept."""

    def __init__(self, model):
        self.model = model
        self._by_frame = {"measurement": Compensator(model, frame="measurement")}
        self._by_name: dict = {}  # frame as requested ("auto" too) -> its compensator, resolved once

    def __call__(self, frame: str):
        c = self._by_name.get(frame)
        if c is None:
            key = resolve_frame(self.model, frame)
            if key not in self._by_frame:
                self._by_frame[key] = Compensator(self.model, frame=key)
            c = self._by_name[frame] = self._by_frame[key]
        return c


def warm_compensator(model) -> _Compensators:
    """The compensators the service holds for its lifetime (built once, at start)."""
    return _Compensators(model)


def step(comps: _Compensators, T: np.ndarray, q_prev: np.ndarray, frame: str, max_step_rad: float | None = None) -> dict:
    """One streamed target ``T`` ``(4, 4)`` from the joints ``q_prev`` ``(n,)`` -> the reply fields.

    ``max_step_rad``: an answer whose revolute joints move further than this (rad) from ``q_prev`` is
    refused (``success`` false, the reason naming the joint and the move); None: no limit."""
    c = comps(frame)
    r = c.step(T, q_prev)
    ok, reason = bool(r.success), r.reason
    if ok and max_step_rad is not None:
        ok, reason = _within_step(c.model.nominal, np.asarray(r.q, dtype=np.float64), q_prev, max_step_rad)
    out = _step_reply(ok, r.command, r.q, r.pos_err_mm, r.ang_err_deg, reason)
    if not ok:
        out.update(in_support=False, support_distance=None)
        return out
    # the CLI's in_support column: where the network correction fades
    out.update({k: v[0] if isinstance(v, list) else v
                for k, v in _support_fields(c.model, np.asarray(r.q, dtype=np.float64)[None], np.array([True]),
                                            "compensated targets").items() if k in ("in_support", "support_distance")})
    return out


def _within_step(robot, q: np.ndarray, q_prev: np.ndarray, max_step_rad: float) -> tuple[bool, str]:
    """``(True, "")`` when no revolute joint of ``q`` lies further than ``max_step_rad`` from ``q_prev``
    (both ``(n,)`` rad; no wrapping: the robot turns a joint by the difference as given); else
    ``(False, reason)`` naming the joint that moves most. Prismatic joints are not limited (m, not deg)."""
    rev = robot.revolute
    d = np.where(rev, np.abs(q - q_prev), 0.0)
    j = int(np.argmax(d))
    if d[j] <= max_step_rad:
        return True, ""
    return False, (f"the answer moves q{j + 1} by {np.degrees(d[j]):.1f} deg from the joints it starts from (the message's "
                   f"'q', else the stream's last answer), over the limit of "
                   f"{np.degrees(max_step_rad):g} deg (hykin serve --max-step-deg): not sent; check the quaternion order "
                   "(x, y, z, qw, qx, qy, qz) and that 'q' is the robot's current joints")


def _step_reply(ok: bool, command, q, pos_err_mm: float, ang_err_deg: float, reason: str) -> dict:
    row = None
    if ok:  # one pose: the row as :func:`pose_rows` writes it
        xyz, quat = se3.transform_to_pose(command)
        row = xyz.tolist() + quat.tolist()
    return {"success": ok, "command": row, "q": np.asarray(q, dtype=np.float64).tolist() if ok else None,
            "pos_err_mm": _float(pos_err_mm), "ang_err_deg": _float(ang_err_deg), "reason": "" if ok else reason}


_NUMBER_TYPES = {int, float}  # JSON numbers as json.loads makes them (bool is neither)


def _fast_rows(v, widths: tuple, limit: int):
    """The float64 array of ``v`` when it is a valid, finite list of rows (or one flat row) of one width
    in ``widths``, at most ``limit`` rows; None otherwise (:func:`matrix` then names the fault). One
    pass over the types in C: no per-number Python check on the common, valid request."""
    if not isinstance(v, list) or not v:
        return None
    rows = v if isinstance(v[0], list) else [v]
    if len(rows) > limit or any(type(r) is not list for r in rows):
        return None
    w = len(rows[0])
    if w not in widths or any(len(r) != w for r in rows) or not set(map(type, itertools.chain.from_iterable(rows))) <= _NUMBER_TYPES:
        return None
    try:
        a = np.array(rows, dtype=np.float64)
    except OverflowError:  # an integer beyond float range
        return None
    return a if np.isfinite(a).all() else None


def _one_row(v, width: int) -> list | None:
    """``v`` as ``width`` finite floats when it is a flat list of that many JSON numbers; None otherwise."""
    if type(v) is not list or len(v) != width or not all(type(x) is float or type(x) is int for x in v):
        return None
    try:
        return [float(x) for x in v] if all(map(math.isfinite, v)) else None
    except OverflowError:  # an integer beyond float range
        return None


def matrix(body: dict, key: str, widths: tuple, limit: int, required: bool = True):
    """``body[key]`` as a finite float64 ``(N, w)`` array, ``w`` in ``widths``, ``N <= limit`` (one
    row may be flat); :class:`RequestError` naming the row and column otherwise."""
    if key not in body or body[key] is None:
        if required:
            raise RequestError(f"missing field '{key}'")
        return None
    v = body[key]
    a = _fast_rows(v, widths, limit)
    if a is not None:
        return a
    if not isinstance(v, list) or not v:
        raise RequestError(f"'{key}' must be a non-empty list of rows")
    if not isinstance(v[0], list):
        v = [v]
    if len(v) > limit:
        raise RequestError(f"'{key}': {len(v)} rows, at most {limit} per request (hykin serve --max-targets)")
    for i, row in enumerate(v):
        if not isinstance(row, list) or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in row):
            raise RequestError(f"'{key}' row {i}: expected a list of numbers")
    lens = {len(r) for r in v}
    if len(lens) != 1 or next(iter(lens)) not in widths:
        raise RequestError(f"'{key}': every row must have {' or '.join(map(str, widths))} numbers, got lengths {sorted(lens)}")
    try:
        a = np.asarray(v, dtype=np.float64)
    except OverflowError:  # an integer beyond float range
        i, j = next((i, j) for i, r in enumerate(v) for j, x in enumerate(r) if abs(x) > 1e308)
        raise RequestError(f"'{key}' row {i}, column {j}: not a finite number") from None
    bad = ~np.isfinite(a)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise RequestError(f"'{key}' row {i}, column {j}: not a finite number")
    return a


def poses(a: np.ndarray, key: str = "targets") -> np.ndarray:
    """``(N, 7)`` rows ``x,y,z,qw,qx,qy,qz`` -> ``(N, 4, 4)``; ``(N, 3)`` positions kept."""
    if a.shape[1] == 3:
        return a
    n = np.linalg.norm(a[:, 3:], axis=1)
    if np.any(np.abs(n - 1) > 1e-3):
        i = int(np.argmax(np.abs(n - 1) > 1e-3))
        raise RequestError(f"'{key}' row {i}: quaternion norm {n[i]:.6f}, expected 1")
    return se3.pose_to_transform(a[:, :3], a[:, 3:] / n[:, None])


def pose_rows(T: np.ndarray, ok: np.ndarray) -> list:
    """``(N, 4, 4)`` -> rows ``x,y,z,qw,qx,qy,qz`` (None where not ``ok``)."""
    xyz, quat = se3.transform_to_pose(np.where(np.isfinite(T), T, np.eye(4)))
    rows = np.concatenate([xyz, quat], 1).tolist()
    return [r if k else None for r, k in zip(rows, ok.tolist())]


def _float(x: float):
    return float(x) if math.isfinite(x) else None


def _floats(a) -> list:
    return [_float(x) for x in np.asarray(a, dtype=np.float64).tolist()]


#: a target farther than this many times the arm's reach from its base is in millimetres, not metres
MM_AS_M_REACHES = 50.0


def check_joints(q: np.ndarray, robot, key: str) -> np.ndarray:
    """``q`` ``(N, dof)`` when it passes the CLI's joint checks (:func:`hykin.io.dataset.validate_joints`:
    degrees passed as radians, the robot's joint limits); :class:`RequestError` naming the field, row,
    column and cause otherwise. A within-limits row of not all whole numbers passes without the full check."""
    from ..io.dataset import DatasetError, validate_joints

    cont = np.asarray(robot.continuous, dtype=bool)
    inside = ((q >= robot.lower - 1e-6) & (q <= robot.upper + 1e-6)) | cont
    if inside.all() and not np.all(np.abs(q - np.round(q)) < 1e-9):
        return q
    names = [f"q{j + 1}" for j in range(q.shape[1])]
    try:
        validate_joints(q, robot, where=key, line_offset=None)
    except DatasetError as e:
        cause = str(e).split(": ", 1)[1] if ": " in str(e) else str(e)
        cause = cause.replace("declare angle_unit='deg' (CLI: --angle-unit deg)", "the service takes radians")
        row = (e.row or 1) - 1
        col = names.index(e.column) if e.column in names else None
        where = f"'{key}' row {row}" + ("" if col is None else f", column {col} ({e.column})")
        raise RequestError(f"{where}: {cause}") from None
    return q


def check_reach(T: np.ndarray, robot, key: str = "targets") -> None:
    """:class:`RequestError` naming the row when a target lies more than :data:`MM_AS_M_REACHES` reaches
    from the robot's base (and from the origin): millimetres passed as metres (the service takes metres)."""
    from ..kinematics.robot import robot_reach_m

    p = T[:, :3] if T.ndim == 2 else T[:, :3, 3]
    reach = float(robot_reach_m(robot))
    d = np.minimum(np.linalg.norm(p - np.asarray(robot.base)[:3, 3], axis=1), np.linalg.norm(p, axis=1))
    far = d > MM_AS_M_REACHES * reach
    if far.any():
        i = int(np.argmax(far))
        raise RequestError(f"'{key}' row {i}: position {d[i]:.6g} m from the robot's base, where the arm reaches "
                           f"{reach:.3g} m: likely millimetres passed as metres (the service takes metres)")


def _support_fields(model, q: np.ndarray, ok: np.ndarray, what: str) -> dict:
    """``in_support`` (the CLI's column: joints inside the model's training support, False where not
    solved), ``support_distance`` (0 inside; None where not solved), ``outside_support`` (count of solved
    rows outside) and a ``warning`` when there are any."""
    from ..hybrid.ik_result import support_of

    dist, sup = support_of(model, q)
    ok = np.asarray(ok, dtype=bool)
    inside = sup & ok
    n_out = int((ok & ~sup).sum())
    out = {"in_support": inside.tolist(), "support_distance": [_float(max(d, 0.0)) if k else None
                                                              for d, k in zip(dist.tolist(), ok.tolist())],
           "outside_support": n_out}
    if n_out:
        out["warning"] = (f"{n_out} {what} need joints outside the model's training support: the correction fades to "
                          "the calibrated model there")
    return out


def check_keys(body, allowed: set) -> dict:
    """``body`` when it is a JSON object with keys in ``allowed`` only."""
    if not isinstance(body, dict):
        raise RequestError("the body must be a JSON object")
    extra = set(body) - allowed
    if extra:
        raise RequestError(f"unknown field(s): {', '.join(sorted(extra))}; allowed: {', '.join(sorted(allowed))}")
    return body


class Handlers:
    """The computations behind the endpoints (plain functions of parsed JSON; testable without HTTP).

    ``model``: a fitted hybrid model; ``max_targets``: rows per request; ``max_step_deg``: the largest
    move (deg, revolute joints) of a streamed answer from the message's joints (None: no limit).
    """

    def __init__(self, model, max_targets: int = 10_000, max_step_deg: float | None = None):
        self.model = model
        self.dof = model.nominal.dof
        self.max_targets = int(max_targets)
        self.max_step_rad = None if max_step_deg is None else math.radians(max_step_deg)
        self.frames = FRAMES
        self.comp = warm_compensator(model)
        from ..kinematics.robot import robot_reach_m

        # a streamed target this far (L1, m) may be in mm: checked in full (a nearer one cannot be)
        self._far_m = MM_AS_M_REACHES * float(robot_reach_m(model.nominal)) * 0.5

    def _targets_q(self, body, widths=(3, 7)):
        a = matrix(body, "targets", widths, self.max_targets)
        qc = matrix(body, "q_current", (self.dof,), self.max_targets, required=False)
        if qc is not None and len(qc) not in (1, len(a)):
            raise RequestError(f"'q_current': {len(qc)} rows, expected 1 or {len(a)}")
        if qc is not None:
            check_joints(qc, self.model.nominal, "q_current")
        check_reach(a, self.model.nominal)
        return poses(a), qc

    def _frame(self, frame):
        if frame not in self.frames:
            raise RequestError(f"'frame' must be one of {', '.join(self.frames)}, got {frame!r}")
        return frame

    # --- POST /fk
    def parse_fk(self, body) -> tuple:
        return (check_joints(matrix(check_keys(body, {"q"}), "q", (self.dof,), self.max_targets), self.model.nominal, "q"),)

    def fk(self, q) -> dict:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            T = self.model.predict(q)
            sup = self.model.support_distance(q) if hasattr(self.model, "support_distance") else np.zeros(len(q))
        return {"poses": pose_rows(T, np.ones(len(q), bool)), "in_support": (np.asarray(sup) <= 0).tolist()}

    # --- POST /ik
    def parse_ik(self, body) -> tuple:
        T, qc = self._targets_q(check_keys(body, {"targets", "q_current"}))
        nom = self.model.nominal
        zero = np.clip(np.zeros(self.dof), nom.lower, nom.upper)
        return T, np.ascontiguousarray(np.broadcast_to(zero if qc is None else qc, (len(T), self.dof))), qc is not None

    def ik(self, T, qc, given: bool = False) -> dict:
        from ..hybrid.ik import hybrid_ik
        from .targets import first_row_per_target

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = hybrid_ik(self.model, T, all_branches=True, q_current=qc, nearest=True)
        N = len(T)
        q = np.full((N, self.dof), np.nan)
        ok = np.zeros(N, bool)
        pe, ae = np.full(N, np.nan), np.full(N, np.nan)
        reason = np.array(["unreachable"] * N, dtype=object)
        k = first_row_per_target(res)
        t = res.target[k]
        q[t], ok[t], pe[t], ae[t], reason[t] = res.q[k], res.success[k], res.pos_err_mm[k], res.ang_err_deg[k], res.reason[k]
        if (~ok).any():  # the CLI's reasons (out of reach with the reach, joint limits, singular, ...)
            from ..kinematics.ik_reasons import failure_reasons

            bad = np.flatnonzero(~ok)
            reason[bad] = failure_reasons(self.model.nominal, T[bad], position_only=T.ndim == 2)
        out = {"q": [r if k else None for r, k in zip(q.tolist(), ok.tolist())], "success": ok.tolist(),
               "pos_err_mm": _floats(pe), "ang_err_deg": _floats(ae), "reason": ["" if k else str(r) for r, k in zip(reason.tolist(), ok.tolist())],
               **_support_fields(self.model, q, ok, "solved targets")}
        if given:  # the CLI's note (hykin ik --seed-joints): a solution on another branch than q_current's
            from ..kinematics.ik_rows import far_from_seed, far_from_seed_note

            far = ok & far_from_seed(self.model.nominal, q, qc)
            out["far_from_q_current"] = far.tolist()
            if far.any():
                out["note"] = far_from_seed_note(np.flatnonzero(far), "q_current")
        return out

    # --- POST /compensate
    def parse_compensate(self, body) -> tuple:
        body = check_keys(body, {"targets", "q_current", "frame"})
        T, qc = self._targets_q(body)
        return T, qc, self._frame(body.get("frame", "measurement"))

    def compensate(self, T, qc, frame) -> dict:
        c = self.comp(frame)(T, q_branch=qc)
        return {"commands": pose_rows(c.command, c.success), "q": [r if k else None for r, k in zip(c.q.tolist(), c.success.tolist())],
                "success": c.success.tolist(), "pos_err_mm": _floats(c.pos_err_mm), "ang_err_deg": _floats(c.ang_err_deg),
                "shift_mm": _floats(c.shift_mm), "status": ["ok" if k else r for r, k in zip(c.reason.tolist(), c.success.tolist())],
                "frame": c.frame, **_support_fields(self.model, c.q, c.success, "compensated targets")}

    # --- WebSocket /stream: one target per message
    def parse_step(self, body, q_last) -> tuple:
        """``{"target": [x,y,z,qw,qx,qy,qz], "q": [..] (optional after the first message), "id": any}``
        -> ``(T (4, 4), q_prev (n,))``; ``q_last``: the connection's last answered joints (or None)."""
        body = check_keys(body, {"target", "q", "id"})
        v = body.get("target")
        if not isinstance(v, list) or (v and isinstance(v[0], list)):
            raise RequestError("'target' must be one row of 7 numbers x, y, z, qw, qx, qy, qz")
        t = _one_row(v, 7)
        n = math.sqrt(t[3] ** 2 + t[4] ** 2 + t[5] ** 2 + t[6] ** 2) if t is not None else 0.0
        if abs(n - 1) <= 1e-3:  # the common, valid message: plain floats, no array checks
            T = se3.pose_to_transform(np.array(t[:3]), np.array(t[3:]) / n)
        else:  # the checks that name the fault
            T = poses(matrix(body, "target", (7,), 1), "target")[0]
        if abs(T[0, 3]) + abs(T[1, 3]) + abs(T[2, 3]) > self._far_m:
            check_reach(T[None], self.model.nominal, "target")
        qv = body.get("q")
        if qv is None:
            if q_last is None:
                raise RequestError(f"'q' (the robot's {self.dof} current joints, rad) is required until a target was answered")
            return T, q_last
        qr = _one_row(qv, self.dof)
        q = np.array(qr) if qr is not None else matrix(body, "q", (self.dof,), 1)[0]
        return T, check_joints(q[None], self.model.nominal, "q")[0]

    def step(self, T, q_prev, frame: str = "measurement") -> dict:
        return step(self.comp, T, q_prev, frame, self.max_step_rad)
