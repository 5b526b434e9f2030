"""URScript targets are compensated for where they are moved to, not where they are written.

Polyscope declares every waypoint at the top of the program (``global Waypoint_1_p=p[...]``), sets the TCP
through variables (``set_tcp(tcp_gripper)``) and writes MoveJ waypoints as ``movej(get_inverse_kin(
Waypoint_1_p, qnear=Waypoint_1_q))``. Checks: the rewritten program, read back by an independent regex and
run by a stand-in UR controller (nominal IK of the flange pose ``cmd · inv(tcp)``, the solution nearest the
current joints, or nearest ``qnear`` for ``get_inverse_kin``; program order), lands the true robot
(:func:`comp_models.exact`: the model's prediction is the truth) within 2e-3 mm of the wanted TCP poses;
unreadable TCPs / ``qnear`` fail their targets with the reason; lines without targets keep every byte.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from comp_models import exact, real_tcp

from hykin import fk
from hykin.compensation import urscript
from hykin.compensation.programs import NUMBER, compensate_program
from hykin.geometry import se3
from hykin.kinematics.ik import ik

_LIT = re.compile(r"p\[\s*" + r"\s*,\s*".join([f"({NUMBER})"] * 6) + r"\s*\]")
HOME = np.array([0.2, -1.5, 1.6, -1.6, -1.5, 0.3])
TCP_A = se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.0, 0.3])), np.array([0.01, 0.0, 0.12]))
TCP_B = se3.make_transform(se3.rotvec_to_matrix(np.array([0.2, -0.1, 0.0])), np.array([-0.02, 0.03, 0.2]))
FLANGE = np.eye(4)


def _p(T) -> str:
    v = (*T[:3, 3], *se3.matrix_to_rotvec(T[:3, :3]))
    return "p[" + ", ".join(f"{x:.9f}" for x in v) + "]"


def _q(q) -> str:
    return "[" + ", ".join(f"{x:.6f}" for x in q) + "]"


def _poses(text: str) -> list:
    """The ``p[...]`` literals of ``text`` in order, as ``(4, 4)`` (independent of the module's parser)."""
    out = []
    for m in _LIT.finditer(text):
        v = np.array([float(g) for g in m.groups()])
        out.append(se3.make_transform(se3.rotvec_to_matrix(v[3:]), v[:3]))
    return out


def _want(m, q, tcp, given=None) -> np.ndarray:
    """The true robot's TCP poses ``(N, 4, 4)`` at joints ``q``: what the program should reach (``given``:
    ``tcp`` is set by the program, e.g. ``set_tcp(p[0, 0, 0, 0, 0, 0])``, the real flange; default: a
    flange-identity ``tcp`` is no ``set_tcp``, the model's TCP)."""
    return real_tcp(m, fk(m.robot_, np.atleast_2d(q)), se3.invert(m.nominal.tool) @ tcp, given)


def _controller(m, text: str, steps: list, q_start) -> np.ndarray:
    """Stand-in UR controller running ``steps`` of ``text`` on the true robot: ``("joints", q)`` a joint
    move; ``(k, tcp, qnear)`` a move to the k-th pose literal of the text with that TCP (flange frame), on
    the nominal solution nearest ``qnear`` (``get_inverse_kin``) or, when None, nearest the current
    joints. Returns the TCP poses reached ``(M, 4, 4)``."""
    nom, P = m.nominal, _poses(text)
    cur, got = np.asarray(q_start, float), []
    for st in steps:
        if isinstance(st[0], str):
            cur = np.asarray(st[1], float)
            continue
        k, tcp, qnear, given = (*st, None)[:4]
        D = se3.invert(nom.tool) @ tcp
        r = ik(nom, (P[k] @ se3.invert(D))[None], all_branches=True).nearest_to(
            cur if qnear is None else np.asarray(qnear, float), nom.lower, nom.upper)
        assert r.success[0]
        cur = r.q[0]
        got.append(real_tcp(m, fk(m.robot_, cur[None])[0], D, given))
    return np.stack(got)


def _err_mm(got, want) -> np.ndarray:
    return np.linalg.norm(got[:, :3, 3] - want[:, :3, 3], axis=1) * 1e3


def _diff_lines(a: str, b: str) -> set:
    la, lb = a.split("\n"), b.split("\n")
    assert len(la) == len(lb)
    return {i for i, (x, y) in enumerate(zip(la, lb), 1) if x != y}


def _other_branch(nom, q) -> np.ndarray:
    """A nominal solution of ``fk(nom, q)`` on another branch than ``q`` (the wrist flipped): what the
    walk would not pick from ``q``, but ``get_inverse_kin`` with a ``qnear`` there does."""
    br = ik(nom, fk(nom, q[None]), all_branches=True)
    Q = np.asarray(br.q).reshape(-1, nom.dof)[np.asarray(br.success).ravel()]
    flip = (np.abs(Q[:, 0] - q[0]) < 1e-6) & (np.sign(Q[:, 2]) == np.sign(q[2])) & (np.sign(Q[:, 4]) != np.sign(q[4]))
    return Q[np.flatnonzero(flip)[0]]


# ---------------------------------------------------------------------------------------- Polyscope


def test_polyscope_program_lands():
    """Waypoints declared first, ``set_tcp(variable)`` after the declarations, MoveJ waypoints through
    ``get_inverse_kin(.., qnear=..)`` (one on the other wrist branch than the walk would take), MoveL
    waypoints: every waypoint lands; the TCP variable, the qnear lists and the header stay as they are."""
    m = exact("ur10", 21)
    nom = m.nominal
    rng = np.random.default_rng(5)
    q1 = HOME + rng.normal(0, 0.05, 6)
    q2 = q1 + rng.normal(0, 0.05, 6)
    q3 = _other_branch(nom, q2 + rng.normal(0, 0.05, 6))  # reached only through its qnear
    q4 = q3 + rng.normal(0, 0.05, 6)
    q5 = q4 + rng.normal(0, 0.05, 6)
    want = np.concatenate([_want(m, np.stack([q1, q2, q3, q4]), TCP_A), _want(m, q5, TCP_B)])
    qn1, qn3 = q1 + 0.02, q3 - 0.02  # taught joints: near, not at, the solutions
    prog = (
        "def Program():\n"
        "  set_standard_analog_input_domain(0, 1)\n"
        "  set_tcp(p[0.0,0.0,0.0,0.0,0.0,0.0])\n"
        f"  global tcp_gripper={_p(TCP_A)}\n"
        f"  global tcp_probe={_p(TCP_B)}\n"
        f"  global Waypoint_1_p={_p(want[0])}\n"
        f"  global Waypoint_1_q={_q(qn1)}\n"
        f"  global Waypoint_2_p={_p(want[1])}\n"
        f"  global Waypoint_3_p={_p(want[2])}\n"
        f"  global Waypoint_3_q={_q(qn3)}\n"
        f"  global Waypoint_5_p={_p(want[4])}\n"
        '  $ 1 "Robot Program"\n'
        "  set_tcp(tcp_gripper)\n"
        '  $ 2 "MoveJ"\n'
        "  movej(get_inverse_kin(Waypoint_1_p, qnear=Waypoint_1_q), a=1.3962634015954636, v=1.0471975511965976)\n"
        '  $ 3 "MoveL"\n'
        "  movel(Waypoint_2_p, a=1.2, v=0.25)\n"
        '  $ 4 "MoveJ"\n'
        "  movej(get_inverse_kin(Waypoint_3_p, qnear=Waypoint_3_q), a=1.3962634015954636, v=1.0471975511965976)\n"
        f"  movel({_p(want[3])}, a=1.2, v=0.25)\n"
        "  set_tcp(tcp_probe)\n"
        "  movel(Waypoint_5_p, a=1.2, v=0.25)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert not res.failed and [t.line for t in res.targets] == [6, 8, 9, 11, 20]
    assert _diff_lines(prog, res.text) == {6, 8, 9, 11, 20}
    assert any("line 4: tcp_gripper is a TCP" in n for n in res.notes)
    # literals in the text: set_tcp, the TCPs, W1, W2, W3, W5, inline W4; executed W1, W2, W3, W4, W5
    steps = [(3, TCP_A, qn1), (4, TCP_A, None), (5, TCP_A, qn3), (7, TCP_A, None), (6, TCP_B, None)]
    got = _controller(m, res.text, steps, HOME)
    assert _err_mm(got, want).max() < 2e-3
    # the same program uncompensated misses by millimetres (the check can fail)
    assert _err_mm(_controller(m, prog, steps, HOME), want).min() > 0.3


# ------------------------------------------------------------------------------- D1: where it is used


def test_declared_waypoints_take_the_branch_of_the_joint_move_before_their_move():
    """Waypoints declared before ``movej([...])``: their branch is the one nearest those joints (the walk
    from zero would take the other elbow), their ``order`` the motion's position."""
    m = exact("ur10", 22)
    nom = m.nominal
    q0 = np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.2])
    q = q0 + np.random.default_rng(6).normal(0, 0.05, (3, 6))
    want = _want(m, q, FLANGE)
    zero_pick = ik(nom, want[:1], all_branches=True).nearest_to(np.zeros(6), nom.lower, nom.upper).q[0]
    assert np.abs(zero_pick - q[0]).max() > 0.5  # the check can fail: from zero another branch is nearest
    prog = (
        "def job():\n"
        f"  global wp_1 = {_p(want[0])}\n"
        f"  global wp_2 = {_p(want[1])}\n"
        f"  movej({_q(q0)}, a=1.4, v=1.05)\n"
        "  movel(wp_1, a=1.2, v=0.25)\n"
        f"  movel({_p(want[2])}, a=1.2, v=0.25)\n"
        "  movel(wp_2, a=1.2, v=0.25)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert not res.failed and _diff_lines(prog, res.text) == {2, 3, 6}
    starts = [prog.index(s) for s in ("movel(wp_1", "movel(wp_2")]
    assert [t.order for t in res.targets] == [starts[0], starts[1], None]
    got = _controller(m, res.text, [("joints", q0), (0, FLANGE, None), (2, FLANGE, None), (1, FLANGE, None)], q0)
    assert _err_mm(got, want[[0, 2, 1]]).max() < 2e-3


def test_movec_points_declared_in_reverse_are_walked_via_point_first():
    """``movec(via, end)`` with both variables declared (end first) before the joint move: the via point is
    executed first, both from the joint move's joints."""
    m = exact("ur10", 30)
    q0 = np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.2])
    q = q0 + np.cumsum(np.random.default_rng(12).normal(0, 0.04, (2, 6)), axis=0)
    want = _want(m, q, FLANGE)
    prog = (
        "def job():\n"
        f"  global c_end = {_p(want[1])}\n"
        f"  global c_via = {_p(want[0])}\n"
        f"  movej({_q(q0)})\n"
        "  movec(c_via, c_end, a=1.2, v=0.1, r=0, mode=0)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert not res.failed and _diff_lines(prog, res.text) == {2, 3}
    via, end = res.targets[1], res.targets[0]
    assert via.order < end.order and np.allclose(via.reset, q0) and end.reset is None
    got = _controller(m, res.text, [(1, FLANGE, None), (0, FLANGE, None)], q0)
    assert _err_mm(got, want).max() < 2e-3


def test_set_tcp_between_declaration_and_move_counts():
    """The TCP of a variable target is the one in effect where it is moved to: a ``set_tcp`` after its
    declaration counts, one before the declaration but replaced before the move does not."""
    m = exact("ur10", 23)
    q = HOME + np.random.default_rng(7).normal(0, 0.05, (3, 6))
    want = np.concatenate([_want(m, q[0], TCP_A), _want(m, q[1], TCP_B), _want(m, q[2], FLANGE, True)])
    prog = (
        "def job():\n"
        f"  global w_a = {_p(want[0])}\n"
        f"  set_tcp({_p(TCP_A)})\n"
        f"  global w_b = {_p(want[1])}\n"
        f"  global w_f = {_p(want[2])}\n"
        f"  movej({_q(HOME)}, a=1.4, v=1.05)\n"
        "  movel(w_a, a=1.2, v=0.25)\n"
        f"  set_tcp({_p(TCP_B)})\n"
        "  movel(w_b, a=1.2, v=0.25)\n"
        "  set_tcp(p[0, 0, 0, 0, 0, 0])\n"
        "  movel(w_f, a=1.2, v=0.25)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert not res.failed and _diff_lines(prog, res.text) == {2, 4, 5}
    got = _controller(m, res.text, [(0, TCP_A, None), (2, TCP_B, None), (3, FLANGE, None, True)], HOME)
    assert _err_mm(got, want).max() < 2e-3


# ------------------------------------------------------------------------------- D2: set_tcp(variable)


def test_set_tcp_variable_is_read_and_its_literal_kept():
    """``set_tcp(name)`` takes ``name``'s latest pose literal before it (text order); that literal is a
    TCP, never a target."""
    m = exact("ur10", 24)
    q = HOME + np.random.default_rng(8).normal(0, 0.05, (2, 6))
    want = np.concatenate([_want(m, q[0], TCP_A), _want(m, q[1], TCP_B)])
    prog = (
        "def job():\n"
        f"  global tcp_gripper = {_p(TCP_A)}\n"
        "  set_tcp(tcp_gripper)\n"
        f"  movej({_q(HOME)}, a=1.4, v=1.05)\n"
        f"  movel({_p(want[0])}, a=1.2, v=0.25)\n"
        f"  tcp_gripper = {_p(TCP_B)}\n"
        "  set_tcp(tcp_gripper)\n"
        f"  movel({_p(want[1])}, a=1.2, v=0.25)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert not res.failed and [t.line for t in res.targets] == [5, 8]
    assert _diff_lines(prog, res.text) == {5, 8}
    got = _controller(m, res.text, [(1, TCP_A, None), (3, TCP_B, None)], HOME)
    assert _err_mm(got, want).max() < 2e-3


@pytest.mark.parametrize("expr", ["pose_trans(tcp_gripper, p[0, 0, 0.01, 0, 0, 0])", "get_tcp_offset()",
                                  "tcp_never_assigned", "tcp_computed"])
def test_unreadable_set_tcp_fails_the_targets_under_it(expr):
    """A ``set_tcp`` whose pose cannot be read makes the targets moved to under it fail with the reason
    (never the robot file's tool assumed); targets before it, and after a readable ``set_tcp``, are
    compensated; the literals inside the ``set_tcp`` are kept."""
    m = exact("ur10", 25)
    q = HOME + np.random.default_rng(9).normal(0, 0.05, (4, 6))
    want = np.concatenate([_want(m, q[:2], TCP_A), _want(m, q[2:], TCP_A)])
    prog = (
        "def job():\n"
        f"  global tcp_gripper = {_p(TCP_A)}\n"
        "  global tcp_computed = pose_trans(tcp_gripper, p[0, 0, 0.01, 0, 0, 0])\n"
        f"  global w_late = {_p(want[1])}\n"
        "  set_tcp(tcp_gripper)\n"
        f"  movel({_p(want[0])}, a=1.2, v=0.25)\n"
        f"  set_tcp({expr})\n"
        "  movel(w_late, a=1.2, v=0.25)\n"
        f"  movel({_p(want[2])}, a=1.2, v=0.25)\n"
        "  set_tcp(tcp_gripper)\n"
        f"  movel({_p(want[3])}, a=1.2, v=0.25)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert [line for line, _ in res.failed] == [4, 9]
    for _, why in res.failed:
        assert f"TCP unknown: set_tcp({expr}) at line 7 could not be read" in why
    assert [t.line for t, ok in zip(res.targets, res.comp.success) if ok] == [6, 11]
    assert _diff_lines(prog, res.text) == {6, 11}


def test_variable_moved_to_under_two_tcps_fails_and_under_one_does_not():
    m = exact("ur10", 26)
    want = _want(m, HOME, TCP_A)
    base = (
        "def job():\n"
        f"  global w = {_p(want[0])}\n"
        f"  movej({_q(HOME)})\n"
        f"  set_tcp({_p(TCP_A)})\n"
        "  movel(w, a=1.2, v=0.25)\n"
        "  set_tcp({tcp})\n"
        "  movel(w, a=1.2, v=0.25)\n"
        "end\n"
    )
    res = compensate_program(m, base.replace("{tcp}", _p(TCP_B)), urscript, frame="measurement")
    assert len(res.failed) == 1 and res.failed[0][0] == 2
    assert "moved to with different TCPs (lines 5, 7)" in res.failed[0][1]
    res = compensate_program(m, base.replace("{tcp}", _p(TCP_A)), urscript, frame="measurement")
    assert not res.failed
    got = _controller(m, res.text, [(0, TCP_A, None)], HOME)
    assert _err_mm(got, want).max() < 2e-3


# --------------------------------------------------------------------------- D3: get_inverse_kin


def test_get_inverse_kin_targets_land_on_the_branch_of_qnear():
    """``movej(get_inverse_kin(pose, qnear))``: inline or variable pose, keyword or positional ``qnear``
    (list or variable), ``tcp=`` (literal or variable) replacing the active TCP for that move; the
    branch is the nominal solution nearest ``qnear`` even where the walk would take another."""
    m = exact("ur10", 27)
    nom = m.nominal
    rng = np.random.default_rng(10)
    q1 = HOME + rng.normal(0, 0.05, 6)
    q2 = _other_branch(nom, q1 + rng.normal(0, 0.05, 6))
    q3 = _other_branch(nom, q2 + rng.normal(0, 0.05, 6))
    q4 = q3 + rng.normal(0, 0.05, 6)
    want = np.concatenate([_want(m, q1, TCP_A), _want(m, q2, TCP_B), _want(m, q3, TCP_A), _want(m, q4, FLANGE, True)])
    walk = ik(nom, want[1:2] @ se3.invert(TCP_B), all_branches=True).nearest_to(q1, nom.lower, nom.upper).q[0]
    assert np.abs(walk - q2).max() > 0.5  # the check can fail: from q1 the walk takes another branch
    qn = [q1 + 0.03, q2 - 0.03, q3 + 0.01, q4]
    prog = (
        "def job():\n"
        f"  global W2 = {_p(want[1])}\n"
        f"  global Q2 = {_q(qn[1])}\n"
        f"  global tcp_b = {_p(TCP_B)}\n"
        f"  set_tcp({_p(TCP_A)})\n"
        f"  movej(get_inverse_kin({_p(want[0])}, qnear={_q(qn[0])}), a=1.4, v=1.05)\n"
        "  movej(get_inverse_kin(W2, qnear=Q2, tcp=tcp_b), a=1.4, v=1.05)\n"
        f"  movej(get_inverse_kin({_p(want[2])}, {_q(qn[2])}), a=1.4, v=1.05)\n"
        f"  movel(get_inverse_kin({_p(want[3])}, qnear={_q(qn[3])}, tcp=p[0, 0, 0, 0, 0, 0]))\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert not res.failed and [t.line for t in res.targets] == [2, 6, 8, 9]
    assert _diff_lines(prog, res.text) == {2, 6, 8, 9}
    assert any("line 9: get_inverse_kin tcp pose kept" in n for n in res.notes)
    steps = [(3, TCP_A, qn[0]), (0, TCP_B, qn[1]), (4, TCP_A, qn[2]), (5, FLANGE, qn[3], True)]
    got = _controller(m, res.text, steps, HOME)
    assert _err_mm(got, want).max() < 2e-3


@pytest.mark.parametrize("args, why", [
    ("qnear=get_joint_positions_somewhere()", "branch unknown: get_inverse_kin qnear=get_joint_positions_somewhere()"),
    ("qnear=q_unknown", "branch unknown: get_inverse_kin qnear=q_unknown at line 3"),
    ("tcp=pose_trans(t0, t1)", "TCP unknown: get_inverse_kin tcp=pose_trans(t0, t1) at line 3 could not be read"),
])
def test_get_inverse_kin_with_an_unreadable_qnear_or_tcp_fails(args, why):
    m = exact("ur10", 28)
    T = _want(m, HOME, FLANGE)[0]
    prog = f"def job():\n  movej({_q(HOME)})\n  movej(get_inverse_kin({_p(T)}, {args}), a=1.4, v=1.05)\nend\n"
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert len(res.failed) == 1 and why in res.failed[0][1]
    assert res.text == prog


def test_get_inverse_kin_without_qnear_walks_from_the_current_joints():
    """No ``qnear`` (or ``get_actual_joint_positions()``): the controller takes the solution nearest the
    current joints, as the walk does from the joint move before; ``tcp="active_tcp"`` is the active TCP."""
    m = exact("ur10", 29)
    q0 = np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.2])
    q = q0 + np.random.default_rng(11).normal(0, 0.05, (2, 6))
    want = _want(m, q, TCP_A)
    prog = (
        "def job():\n"
        f"  global W1 = {_p(want[0])}\n"
        f"  movej({_q(q0)})\n"
        f"  set_tcp({_p(TCP_A)})\n"
        "  movej(get_inverse_kin(W1), a=1.4, v=1.05)\n"
        f"  movej(get_inverse_kin({_p(want[1])}, qnear=get_actual_joint_positions(), tcp=\"active_tcp\"), a=1.4)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert not res.failed and _diff_lines(prog, res.text) == {2, 6}
    got = _controller(m, res.text, [(0, TCP_A, None), (2, TCP_A, None)], q0)
    assert _err_mm(got, want).max() < 2e-3


def test_cli_no_frame_hint_when_targets_fail_for_an_unknown_tcp(tmp_path, capsys):
    """Targets that fail because the script's TCP cannot be read are not 'out of reach': the CLI's
    '--frame base' hint (for most targets unreachable) stays silent; the reason is printed."""
    import warnings

    from cli_run import run
    from comp_models import tiny_model_file

    from hykin.hybrid.model import HybridModel

    model = tiny_model_file()
    m = HybridModel.load(model)
    q = m.nominal.random_joints(3, 4, margin=0.3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        T = m.predict(q)
    lines = ["def job():", "  set_tcp(get_tcp_offset())"]
    for k in range(3):
        rv = se3.matrix_to_rotvec(T[k, :3, :3])
        lines.append("  movel(p[" + ", ".join(f"{v:.7f}" for v in (*T[k, :3, 3], *rv)) + "], a=1.2, v=0.25)")
    prog = tmp_path / "job.script"
    prog.write_text("\n".join(lines + ["end", ""]))
    out = tmp_path / "out.script"
    code, o, err = run(["compensate", model, prog, "-o", out, "--frame", "measurement", "--skip-unreachable"], capsys)
    assert code == 0 and out.read_text() == prog.read_text()
    assert "TCP unknown" in err and "hint:" not in err + o, err + o
