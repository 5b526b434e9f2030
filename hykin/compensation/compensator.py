"""A compensator that stays warm (:class:`Compensator`) and :func:`compensate`, which runs through it.

``Compensator(model)`` loads everything once: the model's compiled hybrid FK (:mod:`hykin.hybrid.fast_fk`,
when the model can run compiled), its frames, joint limits and success tolerance. Then
:meth:`Compensator.step` compensates one target warm-started from the previous joints, and
:meth:`Compensator.__call__` a batch; both run the same code (:meth:`Compensator.solve`), which is also
the code of :func:`compensate`, the CLI ``compensate``, program rewriting and ``hykin serve``.

What is solved (frames and commands: :mod:`hykin.compensation.targets`): for each target, the joints at
which the model's robot (the hybrid model itself) reaches it, on the branch the caller means. The branch
comes from a hint: joints given by the caller (current joints, a program's configuration data matched
to a solution, the previous target's joints); without one, the nominal robot's solution nearest the
previous target's, or — where the nominal robot cannot reach the target — the calibrated robot's, or
the previous joints themselves. The nominal model only hints: a target it cannot reach is still
solved on the hybrid model. Without a hint the batch is then checked as a nearest-joints controller
executes it, target after target (:meth:`Compensator._check_walk`); with given joints (and in
:meth:`Compensator.step`) as a local-IK controller standing at them does (:mod:`.local_controller`).

Solving (compiled models; :mod:`hykin.hybrid.fast_ik`): LM from the hint in ``hint ± max_move_rad``
(within the joint limits) with the classical Jacobian; rows that stop above 1e-9 m / 1e-9 rad are
re-solved from where they stopped with the hybrid (finite-difference) Jacobian within the joint
limits; rows still missing the tolerance from the calibrated robot's closed-form/numerical solutions
nearest the hint (all branches, boundary seeds at the workspace edge). A redundant arm's solutions are
then moved along the self-motion to the one nearest the hint (:mod:`hykin.hybrid.self_motion`).
Models that cannot run compiled (e.g. any object with ``predict``) use :func:`hykin.hybrid.ik.hybrid_ik`
seeded by the hint.

Success tolerance (``tolerance_mm``, ``tolerance_deg``): by default ``tolerance_fraction`` (0.5) of the
model's own held-out mean hybrid error (training metadata: ``val``, else ``held_out``, else ``train``
metrics), at least 1e-4 mm / 1e-4 deg (the hybrid IK's own threshold; also the value for models
without metrics). A solution that misses the target by less than half of what the model itself is
uncertain about is as good as exact for the robot; the LM normally reaches ~1e-12 m anyway. An
under-actuated arm (fewer than 6 joints) matches an arbitrary (measured) pose only in the least-squares
sense: a row at a least-squares solution (the joints cannot reduce the error further) also succeeds
when its error is within the model's accuracy (:func:`hykin.hybrid.ik_result.model_accuracy`, the
held-out maximum error; the rule of :func:`hykin.hybrid.ik.hybrid_ik`). Without a ``q_branch`` the
hints of such an arm are its least-squares solutions, of the branches that fit the target best
(:func:`hykin.compensation.branches.best_fitting`). Failures
carry a categorised reason: ``"blocked by a joint limit: ..."``, ``"unreachable for the model: ..."``
(no solution within the limits near the meant branch; residual given; ``"unreachable for the model: out of
reach, ..."`` when the target is farther from the robot's base than the arm reaches, naming the other
frame as the likely cause; a solver stopped at a limit is called blocked by it only when the calibrated
arm's IK with its revolute limits opened finds the target, else "unreachable for the model: the
calibrated arm reaches it in no configuration, even without joint limits; residual ..."), or the caller's
``branch_reason`` for targets whose branch hint is NaN (configuration data that matched nothing).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..geometry import se3
from ..kinematics.fk import fk
from ..kinematics.ik_solutions import nearest_representation
from ..hybrid.self_motion import is_redundant, toward_hint
from ..kinematics.robot import robot_reach_m
from .frames import fitted_base, other_frame, parse_targets, resolve_frame
from .local_controller import local_picks
from .tool_shift import check_tool_shift, model_delta, tcp_shift_inv, tool_shift_note
from .result import Compensation, edge_notes, first_row_per_target

__all__ = ["Compensator", "StepResult", "compensate", "model_delta", "model_tolerance"]

_FLOOR_MM, _FLOOR_DEG = 1e-4, 1e-4
_POLISH_M = 1e-9  # rows the first solve leaves above this (m, rad) are re-solved with the hybrid Jacobian
_BLOCKED = "blocked by a joint limit"
_POS_ONLY_SEEDS = 8  # numerical position-only IK starts per target for the walk's hints (no closed form)


@dataclass
class StepResult:
    """One compensated target. q: ``(dof,)`` joints (rad / m) the real robot needs (NaN on failure).
    command: ``(4, 4)`` pose to send (controller base frame, m; NaN on failure). success, reason
    (``""`` on success). pos_err_mm, ang_err_deg: the model's pose at ``q`` to the target."""

    q: np.ndarray
    command: np.ndarray
    success: bool
    reason: str
    pos_err_mm: float
    ang_err_deg: float


def model_tolerance(model, fraction: float = 0.5) -> tuple[float, float]:
    """``(mm, deg)``: ``fraction`` of the model's held-out mean hybrid position / orientation error
    (module docstring), at least 1e-4 mm / 1e-4 deg."""
    from ..hybrid.ik_result import model_metrics

    src = model_metrics(model)
    out = []
    for key, floor in (("hybrid_pos_mean_mm", _FLOOR_MM), ("hybrid_rot_mean_deg", _FLOOR_DEG)):
        v = src.get(key)
        out.append(max(floor, fraction * float(v)) if v is not None and np.isfinite(v) else floor)
    return out[0], out[1]


class Compensator:
    """Compensation of targets with ``model`` (a fitted :class:`hykin.HybridModel`, or any model with
    ``nominal``, ``robot_``, ``frame_pre_``, ``frame_post_`` and ``predict``). Loads everything once
    (module docstring); a Compensator holds a snapshot of the model as it is at construction.

    frame: ``"measurement"``, ``"base"`` or ``"auto"`` (:mod:`hykin.compensation.targets`).
    tolerance_mm / tolerance_deg: success tolerance (default from the model's accuracy,
    :func:`model_tolerance` with ``tolerance_fraction``). max_move_rad: half-width of the first box
    around the hint (30°). tool_shift: ``"mount"`` or ``"flange"``, the reading of the calibrated TCP's
    shift where targets carry a program tool (:mod:`.tool_shift`). Other keywords go to :func:`hykin.hybrid.ik.hybrid_ik` (models that cannot run
    compiled)."""

    def __init__(self, model, *, frame: str = "measurement", tolerance_mm: float | None = None,
                 tolerance_deg: float | None = None, tolerance_fraction: float = 0.5,
                 max_move_rad: float = np.radians(30.0), tool_shift: str = "mount", **ik_kw):
        from ..hybrid.ik_result import classical_robot, model_accuracy, underactuated

        self.model = model
        self.nominal = model.nominal
        self.robot = classical_robot(model)
        self.dof = self.nominal.dof
        self.frame = resolve_frame(model, frame)
        tm, td = model_tolerance(model, tolerance_fraction)
        self.tolerance_mm = float(tm if tolerance_mm is None else tolerance_mm)
        self.tolerance_deg = float(td if tolerance_deg is None else tolerance_deg)
        if not (self.tolerance_mm > 0 and self.tolerance_deg > 0):
            raise ValueError(f"tolerances must be > 0, got {self.tolerance_mm} mm, {self.tolerance_deg} deg")
        self.max_move_rad = float(max_move_rad)
        self.tool_shift = check_tool_shift(tool_shift)  # where program tools sit (.tool_shift)
        self._lsq = None  # (m, rad): an under-actuated arm's least-squares acceptance (module docstring)
        am, ad = model_accuracy(model)
        self.accuracy_mm = max(self.tolerance_mm, am or 0.0)  # the model's own (held-out max) error, mm
        # a full arm's least-squares solutions are at its reach boundary (stretched elbow): the model's boundary
        # lies within its own accuracy of the real one (probe s42 AQ: 22 of 450 stretched-elbow targets the real
        # robot reaches were refused, missing by 0.010-0.027 mm where the model's max error was 0.062 mm)
        if underactuated(self.robot, False) or not is_redundant(self.dof, False):
            self._lsq = (self.accuracy_mm * 1e-3, np.radians(max(self.tolerance_deg, ad or 0.0)))
        self.ik_kw = ik_kw
        self.lower = np.asarray(self.robot.lower, dtype=np.float64)
        self.upper = np.asarray(self.robot.upper, dtype=np.float64)
        self._rev = self.robot.revolute  # (dof,) like the limits
        self._base_fit = fitted_base(model) if self.frame == "base" else None
        self._nom_base_inv = se3.invert(self.nominal.base)
        # targets in the measurement frame, seen from the controller's base (the shift): through the fitted
        # base where it is far from the nominal one (a tracker's frame), else as the controller places them
        self._ctrl_of_meas = (se3.invert(fitted_base(model)) if resolve_frame(model, "auto") == "base"
                              else self._nom_base_inv)
        self._pre_inv = se3.invert(np.asarray(model.frame_pre_, dtype=np.float64))
        self._post = np.asarray(model.frame_post_, dtype=np.float64)
        self._post_inv = se3.invert(self._post)
        # the model's (calibrated, registered) TCP relative to the robot file's: where a program tool given
        # relative to the file's TCP sits on the real robot (model_targets)
        self._tcp_shift_inv = tcp_shift_inv(model)
        self._reach_m = robot_reach_m(self.robot)
        self.kernel = None
        if not ik_kw and hasattr(model, "net_pos_"):
            from ..hybrid.fast_fk import kernel_of

            self.kernel = kernel_of(model)

    # ------------------------------------------------------------------ public API

    def step(self, target, q_prev) -> StepResult:
        """Compensate ONE target ``(4, 4)`` (m, in :attr:`frame`) on the branch of ``q_prev`` ``(dof,)``
        (the previous target's joints: the warm start). Same code as :meth:`__call__`."""
        T = np.asarray(target, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"step: target must be a finite (4, 4) pose, got shape {T.shape}")
        qp = np.asarray(q_prev, dtype=np.float64).reshape(1, self.dof)
        fast = self._step_compiled(T, qp)
        if fast is not None and (self.dof != 6 or np.abs(local_picks(self.nominal, fast.command[None], None, qp)[0]
                                                        - fast.q).max() <= 1e-6):
            return fast  # the controller at q_prev executes the command at these joints (else the batch's check)
        c = self(T[None], q_branch=qp)
        return StepResult(q=c.q[0], command=c.command[0], success=bool(c.success[0]), reason=str(c.reason[0]),
                          pos_err_mm=float(c.pos_err_mm[0]), ang_err_deg=float(c.ang_err_deg[0]))

    def __call__(self, targets, q_branch=None, *, tool_delta=None, position_only: bool = False,
                 branch_reason: str | np.ndarray = "no solution on the requested branch", tool_given=None,
                 controller_check: bool = True) -> Compensation:
        """Compensate targets ``(N, 4, 4)`` (or ``(N, 3)`` positions), m, in :attr:`frame`.

        ``q_branch`` ``(N, dof)`` / ``(dof,)``: joints choosing each target's branch, the joints the robot
        stands at (NaN rows: no branch, the target fails with ``branch_reason``: one text, or ``(N,)`` texts
        per row); each command is then executed as a local-IK controller from them would
        (:mod:`.local_controller`; ``controller_check=False``: not, for callers with checks of their own);
        default the walk of the module docstring. ``tool_delta``: :mod:`hykin.compensation.targets`;
        ``tool_given`` ``(N,)`` bool: the rows whose ``tool_delta`` is a program's tool (default all;
        :meth:`model_delta`). Returns a :class:`Compensation`."""
        from ..hybrid.ik_result import support_of

        T, pos_in = parse_targets(targets)
        pos_only = bool(position_only or pos_in)
        N, n = len(T), self.dof
        D = None if tool_delta is None else np.broadcast_to(np.asarray(tool_delta, dtype=np.float64), (N, 4, 4))
        G = None if tool_given is None else np.broadcast_to(np.asarray(tool_given, dtype=bool), (N,))
        Dm = self.model_delta(D, G)
        local = q_branch is None and N > 1 and self._redundant(pos_only) and not pos_only
        if q_branch is None:
            qb = self._walk(T, D, pos_only, Dm)
            if local:  # a redundant arm walks from the joints before (.redundant_walk)
                from .redundant_walk import local_hints

                qb = local_hints(self, T, qb, D, Dm, pos_only, branch_reason)
        else:
            qb = np.array(np.broadcast_to(np.asarray(q_branch, dtype=np.float64), (N, n)))
        q, cmd, ok, reason, pe, ae = self.solve(T, qb, D, pos_only, branch_reason, D_model=Dm)
        comp = Compensation(command=cmd, q=q, success=ok, reason=reason, pos_err_mm=pe, ang_err_deg=ae,
                            shift_mm=np.full(N, np.nan), shift_deg=np.full(N, np.nan), in_support=ok.copy(),
                            q_branch=qb, frame=self.frame)
        # (a redundant arm's controller resolves the redundancy its own way: its lists have their own check)
        if q_branch is not None and controller_check and not pos_only and n == 6:
            from .local_controller import check_from_joints

            comp.reason = comp.reason.astype(object)
            comp.notes = check_from_joints(self.model, self, comp, T, D, Dm, qb)
            comp.reason = comp.reason.astype(str)
        self._shifts(comp, T, pos_only)
        if local:
            from .redundant_walk import check_local

            comp.reason = comp.reason.astype(object)
            comp.notes = [REDUNDANT_NOTE] + check_local(self.model, self, comp, T, D, Dm)
            comp.reason = comp.reason.astype(str)
        elif q_branch is None and not pos_only and N > 1 and n >= 6:
            self._check_walk(comp, T, D, G, Dm, branch_reason)
        comp.in_support = support_of(self.model, comp.q)[1] & comp.success
        if n >= 6 and controller_check:
            comp.notes = comp.notes + edge_notes(comp, self.tolerance_mm, self.tolerance_deg, self.accuracy_mm)
        if D is not None and controller_check:  # (not the internal calls of the walk or the programs)
            sent = comp.success if G is None else comp.success & G  # (the targets compensated: probe s42 AX)
            comp.notes = comp.notes + tool_shift_note(self.model, D, sent, self.tool_shift, self.accuracy_mm)
        return comp

    def _shifts(self, comp: Compensation, T: np.ndarray, pos_only: bool) -> None:
        """``comp.shift_mm`` / ``shift_deg`` (in place): each command from its target, seen from the base."""
        T_ctrl, ok = (T if self.frame == "base" else self._ctrl_of_meas @ T), comp.success
        comp.shift_mm = np.linalg.norm(comp.command[:, :3, 3] - T_ctrl[:, :3, 3], axis=1) * 1e3
        comp.shift_deg = np.full(len(T), np.nan)
        if ok.any() and not pos_only:
            comp.shift_deg[ok] = se3.pose_error(comp.command[ok], T_ctrl[ok])[1]

    def _check_walk(self, comp: Compensation, T: np.ndarray, D, G, Dm, branch_reason) -> None:
        """The walk's targets as the controller executes them (in place; a program's check,
        :func:`.walk_checks.check_walk`): each from the compensated joints of the one before, on the
        nominal solution of its command nearest them. Where that is not the compensated solution (two
        solutions near a tie from there: a ±360° wrist half a turn away, probe s40 V: 22 of 297 random
        targets landed 0.4-11 mm off) the target is solved again on the controller's choice; one that
        the controller still executes elsewhere fails with the reason, or is noted (``comp.notes``) where
        that lands within the model's accuracy. Arms of fewer than 6 joints reach a pose only in the
        least-squares sense: not checked (as programs). The shifts are recomputed for rows solved again."""
        from .walk_checks import WalkRow, check_walk, take_other_branches

        N = len(T)
        Dc = np.broadcast_to(np.eye(4), (N, 4, 4)) if D is None else D
        rows_t = [WalkRow(k) for k in range(N)]
        rows_t[0].reset = self._walk_start()

        def solve(rows, hints):
            return self(T[rows], q_branch=hints, tool_delta=None if D is None else D[rows],
                        tool_given=None if G is None else G[rows], branch_reason=branch_reason, controller_check=False)

        comp.reason = comp.reason.astype(object)
        take_other_branches(self, comp, T, Dm, solve)  # a near tie: the check decides the controller's branch
        comp.notes = check_walk(self.model, self, solve, rows_t, comp, comp.q_branch.copy(), T, Dc, Dm, None,
                                T_nominal=self.nominal_world(T, D))
        comp.reason = comp.reason.astype(str)

    # ------------------------------------------------------------------ the one path

    def model_targets(self, T: np.ndarray, D: np.ndarray | None = None) -> np.ndarray:
        """Targets ``(N, 4, 4)`` in :attr:`frame` (of a TCP ``D`` relative to the model's TCP: :meth:`model_delta`)
        -> the model's measurement frame."""
        Tm = T if self._base_fit is None else self._base_fit @ T
        return Tm if D is None else Tm @ se3.invert(D)

    def model_delta(self, D: np.ndarray | None, given=None) -> np.ndarray | None:
        """:func:`model_delta` of this compensator's model."""
        return model_delta(self.model, D, given, self._tcp_shift_inv, self.tool_shift)

    def solve(self, T: np.ndarray, hint: np.ndarray, D: np.ndarray | None = None, pos_only: bool = False,
              branch_reason: str | np.ndarray = "no solution on the requested branch", D_model=None):
        """Targets ``(N, 4, 4)`` (:attr:`frame`) and branch hints ``(N, dof)`` -> ``(q, command, success,
        reason, pos_err_mm, ang_err_deg)``, NaN joints and command where unsuccessful. ``D``: the program
        TCP relative to the robot file's (the command's); ``D_model``: relative to the model's
        (:meth:`model_delta`; default ``model_delta(D)``)."""
        N, n = len(T), self.dof
        Tm = self.model_targets(T, self.model_delta(D) if D_model is None else D_model)
        has = np.isfinite(hint).all(1)
        every = bool(has.all())  # the usual case: no index arrays, no copies
        idx = slice(None) if every else np.flatnonzero(has)
        if every:
            q, pe, ae = np.empty((N, n)), np.empty(N), np.empty(N)
        else:
            q, pe, ae = np.full((N, n), np.nan), np.full(N, np.nan), np.full(N, np.nan)
        ok = has.copy()
        reason = None if every else np.where(has, "", branch_reason).astype(object)
        if every or idx.size:
            h, Ti = (hint, Tm) if every else (hint[idx], Tm[idx])
            if self.kernel is not None:
                if ((h < self.lower) | (h > self.upper)).any():  # outside the limits by a turn: the representation inside
                    h = np.where(self._rev, nearest_representation(h, h, self.lower, self.upper), h)
                qi, pi, ai, ri = self._solve_compiled(Ti, np.minimum(np.maximum(h, self.lower), self.upper), pos_only)
            else:
                qi, pi, ai, ri = self._solve_generic(Ti, h, pos_only)
            if ri is not None and not pos_only:
                self._wrist_retry(Ti, h, qi, pi, ai, ri)
                ri = None if (ri == "").all() else ri
            q[idx], pe[idx], ae[idx] = qi, pi, ai
            if ri is not None:  # some rows failed (None: every row succeeded)
                if reason is None:
                    reason = np.full(N, "", dtype=object)
                reason[idx] = ri
                ok[idx] = ri == ""
        if reason is not None:
            q[~ok] = np.nan
            qo = q[ok]
        else:
            qo = q
        cmd = None if reason is None and len(qo) else np.full((N, 4, 4), np.nan)  # NaN only where a row failed
        if len(qo):
            C = fk(self.nominal, qo[0])[None] if len(qo) == 1 else fk(self.nominal, qo)
            C = self._nom_base_inv @ C if D is None else self._nom_base_inv @ C @ D[ok]
            if cmd is None:
                cmd = C
            else:
                cmd[ok] = C
        if reason is not None:
            self._name_out_of_reach(Tm, has & ~ok, reason)
            if not pos_only:
                self._confirm_limits(Tm, has & ~ok, reason)
        reason = np.zeros(N, dtype="<U1") if reason is None else reason.astype(str)  # "" where successful
        return q, cmd, ok, reason, pe, ae

    def _wrist_retry(self, Tm, h, q, pe, ae, reason) -> None:
        """In place: failed rows whose hint lies near the wrist singularity solved again from the hint with
        the A4/A6 split turned (:func:`.branches.wrist_split_seeds`); the smallest turn that succeeds is kept."""
        from .branches import wrist_split_seeds

        fail = np.flatnonzero(reason != "")
        j, H = wrist_split_seeds(self.nominal, h[fail])
        if not j.size:
            return
        r = fail[j]
        solve = self._solve_compiled if self.kernel is not None else self._solve_generic
        q2, p2, a2, r2 = solve(Tm[r], H, False)
        ok2 = np.ones(len(r), dtype=bool) if r2 is None else r2 == ""
        for k in np.unique(r[ok2]):
            i = np.flatnonzero(ok2 & (r == k))[0]  # seeds come in order of the turn: the smallest first
            q[k], pe[k], ae[k], reason[k] = q2[i], p2[i], a2[i], ""

    def robot_world(self, Tm: np.ndarray) -> np.ndarray:
        """Targets ``(N, 4, 4)`` in the model's measurement frame -> the calibrated robot's TCP in its world."""
        return self._pre_inv @ Tm @ self._post_inv

    def _first_box(self, hint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The first solve's box: ``hint ± max_move_rad`` within the joint limits (``hint`` ``(..., dof)``)."""
        return np.maximum(self.lower, hint - self.max_move_rad), np.minimum(self.upper, hint + self.max_move_rad)

    def _name_out_of_reach(self, Tm: np.ndarray, failed: np.ndarray, reason: np.ndarray) -> None:
        """Rewrite (in place) the reason of ``failed`` rows whose target ``Tm`` (measurement frame) lies
        beyond the calibrated arm's reach from its base (:func:`hykin.kinematics.robot.robot_reach_m`, an
        upper bound over all joints; plus 1 % and 5 mm for the networks' corrections): the cause is then
        the target's place (often its frame), not a joint limit that the solver ran into on the way."""
        i = np.flatnonzero(failed)
        if not i.size:
            return
        F = fitted_base(self.model)  # the same targets read in the other frame (probe s42 AR: a frame 5 mm off named)
        dist = lambda P: np.linalg.norm(self.robot_world(P)[:, :3, 3] - self.robot.base[:3, 3], axis=1)
        d, d_other = dist(Tm[i]), dist((se3.invert(F) if self.frame == "base" else F) @ Tm[i])
        reach = 1.01 * self._reach_m + 0.005
        far = d > reach
        other, where = other_frame(self.frame)
        for k, dk, do in zip(i[far], d[far], d_other[far]):
            hint = f" (targets in {where}? frame '{other}')" if do <= reach else ""
            reason[k] = (f"unreachable for the model: out of reach, {dk * 1e3:.0f} mm from the robot's base where it "
                         f"reaches {self._reach_m * 1e3:.0f} mm at most{hint}")

    def _confirm_limits(self, Tm: np.ndarray, failed: np.ndarray, reason: np.ndarray) -> None:
        """Check (in place) the ``failed`` rows said to be blocked by a joint limit: the solver stopped at
        a limit, but was the limit the cause? The calibrated arm's IK with its revolute limits opened to
        ±2π (every branch, the closed form of :func:`hykin.hybrid.ik_seeds.seed_robot_of` as seeds)
        decides: a solution there keeps the reason; none rewrites it to "unreachable for the model: the
        calibrated arm reaches it in no configuration, even without joint limits" (the residual kept)."""
        i = np.array([k for k in np.flatnonzero(failed) if str(reason[k]).startswith(_BLOCKED)], dtype=np.int64)
        if not i.size:
            return
        from ..hybrid.ik_seeds import seed_robot_of
        from ..kinematics.ik import ik
        from ..kinematics.ik_reasons import open_revolute_limits

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            br = ik(open_revolute_limits(self.robot), self.robot_world(Tm[i]), all_branches=True,
                    seed_robot=seed_robot_of(self.model, None))
        none = ~np.asarray(br.success, dtype=bool).reshape(len(i), -1).any(1)
        for k in i[none]:
            reason[k] = ("unreachable for the model: the calibrated arm reaches it in no configuration, even without "
                         "joint limits" + str(reason[k])[len(_BLOCKED):].replace(": residual", "; residual", 1))

    def _step_compiled(self, T: np.ndarray, hint: np.ndarray) -> StepResult | None:
        """The usual step without :meth:`solve`'s bookkeeping: a compiled model, a hint ``(1, dof)`` within
        the joint limits and a first solve that converges (below 1e-9 m / rad). The same kernel call on the
        same arrays as :meth:`_solve_compiled`'s first solve, and the same command, so the same numbers;
        None otherwise (the caller runs :meth:`solve`, which starts with that same first solve)."""
        k, lo_j, hi_j = self.kernel, self.lower, self.upper
        h = hint[0]
        if k is None or not ((h >= lo_j).all() and (h <= hi_j).all()):  # NaN or outside: the general path
            return None
        from ..hybrid.fast_ik import solve_packed_rows

        Tm = T if self._base_fit is None else self._base_fit @ T
        q = hint.copy()
        lo, hi = self._first_box(hint)
        pe, ae = solve_packed_rows(k, np.ascontiguousarray(Tm[None]), q, lo, hi)
        pe_m, ae_rad = float(pe[0]), float(ae[0])
        if pe_m > _POLISH_M or ae_rad > _POLISH_M:
            return None
        pe_mm, ae_deg = pe_m * 1e3, float(np.degrees(ae_rad))
        if not (pe_mm <= self.tolerance_mm and ae_deg <= self.tolerance_deg):
            return None
        if self._redundant(False):  # as the batch path does after its first solve
            pe_a, ae_a = np.array([pe_m]), np.array([ae_rad])
            self._toward_hint(Tm[None], q, pe_a, ae_a, hint, np.zeros(1, dtype=np.int64), False)
            pe_mm, ae_deg = float(pe_a[0]) * 1e3, float(np.degrees(ae_a[0]))
        return StepResult(q=q[0], command=self._nom_base_inv @ fk(self.nominal, q[0]), success=True, reason="",
                          pos_err_mm=pe_mm, ang_err_deg=ae_deg)

    def _redundant(self, pos_only: bool) -> bool:
        return is_redundant(self.dof, pos_only)

    def _toward_hint(self, Tm, q, pe, ae, hint, rows, pos_only) -> None:
        """:func:`hykin.hybrid.self_motion.toward_hint` with this compensator's solve and tolerance
        (``pe``/``ae`` in m/rad, updated in place with ``q``)."""
        from ..hybrid.fast_ik import solve

        def solve_rows(idx, q0):
            q2, p2, a2, _ = solve(self.kernel, Tm[idx], q0, self.lower, self.upper, position_only=pos_only)
            return q2, p2, a2

        toward_hint(solve_rows, self._ok, self.robot, self._post, q, pe, ae, hint, self.lower, self.upper, rows,
                    pos_only)

    def _ok(self, pe_m, ae_rad):
        return (pe_m * 1e3 <= self.tolerance_mm) & (np.degrees(ae_rad) <= self.tolerance_deg)

    def _solve_compiled(self, Tm, hint, pos_only):
        from ..hybrid.fast_ik import solve

        k, lo_j, hi_j = self.kernel, self.lower, self.upper
        lo, hi = self._first_box(hint)
        q, pe, ae, _ = solve(k, Tm, hint, lo, hi, position_only=pos_only)
        bad = (pe > _POLISH_M) | (ae > _POLISH_M)  # stalled (even within the tolerance): polish
        if bad.any():  # the hybrid Jacobian, from where they stopped, within the joint limits
            i = np.flatnonzero(bad)
            q2, p2, a2, _ = solve(k, Tm[i], q[i], lo_j, hi_j, position_only=pos_only, fd=True)
            self._keep_better(i, q, pe, ae, q2, p2, a2)
            bad = ~self._ok(pe, ae)
        if bad.any() and not pos_only:  # the calibrated robot's solutions nearest the hint
            i = np.flatnonzero(bad)
            seeds = self._calibrated_seeds(Tm[i], hint[i])
            f = np.isfinite(seeds).all(1)
            if f.any():
                j = i[f]
                q3, p3, a3, _ = solve(k, Tm[j], np.clip(seeds[f], lo_j, hi_j), lo_j, hi_j, position_only=pos_only,
                                      fd=True)
                self._keep_better(j, q, pe, ae, q3, p3, a3)
        ok = self._ok(pe, ae)
        if self._redundant(pos_only):  # the solution nearest the hint along the self-motion
            self._toward_hint(Tm, q, pe, ae, hint, np.flatnonzero(ok), pos_only)
        if not ok.all() and self._lsq is not None and not pos_only:
            ok = self._least_squares_ok(Tm, q, pe, ae, ok)
        reason = None  # every row within the tolerance
        if not ok.all():
            at_lim = ((q <= lo_j + 1e-9) | (q >= hi_j - 1e-9)).any(1)
            what = np.where(at_lim, _BLOCKED, "unreachable for the model")
            ang, tol = ("", "") if pos_only else (" / {:.3g} deg", f" / {self.tolerance_deg:.3g} deg")
            reason = np.array(["" if o else (f"{w}: residual {p * 1e3:.3g} mm" + ang.format(np.degrees(a))
                                             + f" (tolerance {self.tolerance_mm:.3g} mm{tol})")
                               for o, w, p, a in zip(ok, what, pe, ae)], dtype=object)
        return q, pe * 1e3, np.degrees(ae), reason

    def _least_squares_ok(self, Tm, q, pe, ae, ok) -> np.ndarray:
        """``ok`` plus the rows at a least-squares solution within the model's accuracy (under-actuated
        arms; module docstring), not on a joint limit. ``pe``, ``ae``: m, rad."""
        from ..hybrid.ik_solve import IKProblem, accept_least_squares, stationary

        def at_least_squares(i):
            prob = IKProblem(self.model, self.robot, Tm[i], False, 1.0)
            return stationary(prob, q[i], np.arange(i.size), self.tolerance_mm * 1e-3, np.radians(self.tolerance_deg),
                              self.max_move_rad)

        at_lim = ((q <= self.lower + 1e-9) | (q >= self.upper - 1e-9)).any(1)
        return accept_least_squares(ok, at_lim, pe, ae, self._lsq, at_least_squares)

    @staticmethod
    def _keep_better(i, q, pe, ae, q2, p2, a2) -> None:
        better = p2 + a2 < pe[i] + ae[i]
        j = i[better]
        q[j], pe[j], ae[j] = q2[better], p2[better], a2[better]

    def _calibrated_seeds(self, Tm, hint) -> np.ndarray:
        """Per target the calibrated robot's IK solution (every branch, boundary seeds) nearest ``hint``."""
        from ..hybrid.ik_seeds import classical_seeds, seed_robot_of
        from ..kinematics.ik import nearest_representation

        Tr = self.robot_world(Tm)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            q0, _, _ = classical_seeds(self.robot, Tr, all_branches=True, seed_robot=seed_robot_of(self.model, None))
        if q0.ndim == 2:
            q0 = q0[:, None]
        q0 = nearest_representation(q0, hint[:, None], self.lower, self.upper)
        d = np.where(np.isfinite(q0).all(2), np.linalg.norm(np.nan_to_num(q0 - hint[:, None]), axis=2), np.inf)
        k = np.argmin(d, axis=1)
        out = q0[np.arange(len(q0)), k].copy()
        out[~np.isfinite(d[np.arange(len(q0)), k])] = np.nan
        return out

    def _solve_generic(self, Tm, hint, pos_only):
        from ..hybrid.ik import hybrid_ik

        kw = {"success_mm": self.tolerance_mm, "success_deg": self.tolerance_deg, **self.ik_kw}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # out-of-support is reported per row (in_support)
            res = hybrid_ik(self.model, Tm[:, :3, 3] if pos_only else Tm, all_branches=False, q_current=hint,
                            nearest=True, position_only=pos_only, **kw)
        first = first_row_per_target(res)
        M, n = len(Tm), self.dof
        q, pe, ae = np.full((M, n), np.nan), np.full(M, np.nan), np.full(M, np.nan)
        reason = np.full(M, "unreachable for the model", dtype=object)
        t = res.target[first]
        q[t], pe[t], ae[t] = res.q[first], res.pos_err_mm[first], res.ang_err_deg[first]
        reason[t] = np.where(res.success[first], "", np.where(res.reason[first] != "", res.reason[first].astype(object),
                                                              "unreachable for the model"))
        return q, pe, ae, reason

    def _walk_start(self) -> np.ndarray:
        """The joints the walk starts from (the controller's before the first target): zero within the limits."""
        return np.clip(np.zeros(self.dof), self.nominal.lower, self.nominal.upper)

    def nominal_world(self, T: np.ndarray, D=None) -> np.ndarray:
        """Targets ``(N, 4, 4)`` (:attr:`frame`; of a TCP ``D`` relative to the robot file's) -> the robot
        file's TCP in the nominal robot's world, where the walk takes the nominal solutions as hints."""
        T_nom = self.nominal.base @ T if self.frame == "base" else T
        return T_nom if D is None else T_nom @ se3.invert(D)

    def _walk(self, T: np.ndarray, D, pos_only: bool, Dm=None) -> np.ndarray:
        """Branch hints without ``q_branch`` (module docstring): nominal solutions nearest the previous
        target's; where the nominal robot has none, the calibrated robot's, else the previous joints."""
        from ..hybrid.ik_seeds import LSQ_SEED
        from ..kinematics.ik import ik
        from .branches import best_fitting, nearest_candidate, sequential_nearest, walk_nearest

        nom, N, n = self.nominal, len(T), self.dof
        start = self._walk_start()
        if pos_only:  # no closed form for positions: the calibrated robot's numerical solutions from a few
            # fixed seeds (in its own world: a tracker-frame model's base is metres from the nominal one), walked
            Tr = self.robot_world(self.model_targets(T, None))
            seeds = np.vstack([start, nom.random_joints(_POS_ONLY_SEEDS - 1, 0, margin=0.1)])
            sols = [ik(self.robot, Tr, q_seed=s, position_only=True) for s in seeds]
            qb = walk_nearest(self.robot, np.stack([r.q for r in sols], 1), np.stack([r.success for r in sols], 1))
            return np.where(np.isfinite(qb).all(1, keepdims=True), qb, start)
        T_nom = self.nominal_world(T, D)
        qb = sequential_nearest(nom, T_nom, None, polish=False, least_squares=LSQ_SEED)  # hints: solved on the model next
        miss = np.flatnonzero(~np.isfinite(qb).all(1))
        if miss.size:
            Tr = self.robot_world(self.model_targets(T[miss], None if Dm is None else Dm[miss]))
            br = ik(self.robot, Tr, all_branches=True, least_squares=LSQ_SEED)
            qc = np.asarray(br.q, dtype=np.float64).reshape(len(miss), -1, n)
            okc = best_fitting(np.asarray(br.success, dtype=bool).reshape(len(miss), -1), br.pos_err_m, br.ang_err_rad)
            for j, i in enumerate(miss):  # few rows: the walk continues from the joints before
                prev = next((qb[k] for k in range(i - 1, -1, -1) if np.isfinite(qb[k]).all()), start)
                pick = nearest_candidate(self.robot, qc[j], okc[j], prev)
                qb[i] = prev if pick is None else pick
        return qb


#: said with every walk of a redundant arm (:mod:`.redundant_walk`): its controller resolves the redundancy
REDUNDANT_NOTE = ("a redundant arm without joints per target: the commands hold where the controller takes the "
                  "compensated joints, solving each command locally from the joints of the one before (as checked "
                  "here with a least-norm IK) after reaching the first target's joints; a controller resolving the "
                  "redundancy otherwise (another solver, an arm angle or status of its own) reaches the same poses "
                  "on other joints, where the model's corrections differ (probe s41: 0.5-1.5 mm). Give the joints "
                  "(q1..qN columns) or send them (--joints)")


def compensate(model, T_target, *, q_branch=None, frame: str = "measurement", position_only: bool = False,
               tool_delta=None, branch_reason: str | np.ndarray = "no solution on the requested branch", tool_given=None,
               **kw) -> Compensation:
    """Compensated commands for targets ``T_target`` ``(N, 4, 4)`` (or ``(N, 3)`` positions), m:
    ``Compensator(model, frame=frame, **kw)(T_target, q_branch, ...)`` (:class:`Compensator`).

    ``q_branch`` ``(N, n)`` or ``(n,)``: joints choosing the branch (current joints, or the solution the
    program means); NaN rows = no branch (the target fails with ``branch_reason``). Default: the walk of
    :class:`Compensator`. ``frame``, ``tool_delta``: :mod:`hykin.compensation.targets`; ``tool_given``:
    :meth:`Compensator.__call__`. ``kw``: tolerances,
    ``max_move_rad`` (:class:`Compensator`); other keywords go to :func:`hykin.hybrid.ik.hybrid_ik`."""
    return Compensator(model, frame=frame, **kw)(T_target, q_branch, tool_delta=tool_delta, position_only=position_only,
                                                 branch_reason=branch_reason, tool_given=tool_given)
