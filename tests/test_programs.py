"""Program rewriting (URScript, KRL, RAPID) on samples of the published syntax.

Checks: the number of targets found, every line without a target byte for byte unchanged, the
rewritten numbers parsed back and executed by a stand-in controller (nominal IK on the branch the
program's data mean) land on the true robot, configuration data consistent with the joints,
conversions against scipy's Euler angles.
"""

from __future__ import annotations

import numpy as np
import pytest
from comp_models import exact, real_tcp
from scipy.spatial.transform import Rotation

from hykin import fk
from hykin.compensation import compensate, krl, rapid, urscript
from hykin.compensation.branches import (
    abb_confdata,
    kuka_status,
    match_abb_confdata,
    match_kuka_status,
)
from hykin.compensation.programs import compensate_program
from hykin.geometry import se3
from hykin.kinematics.ik import ik


def _diff_lines(a: str, b: str) -> set:
    la, lb = a.split("\n"), b.split("\n")
    assert len(la) == len(lb)
    return {i for i, (x, y) in enumerate(zip(la, lb), 1) if x != y}


def _p(T, rv=None) -> str:
    rv = se3.matrix_to_rotvec(T[:3, :3]) if rv is None else rv
    return "p[" + ", ".join(f"{v:.6f}" for v in (*T[:3, 3], *rv)) + "]"


def test_urscript_rewrite():
    m = exact("ur10", 11)
    nom = m.nominal
    home = np.array([0.2, -1.5, 1.6, -1.6, -1.5, 0.3])
    q = home + np.random.default_rng(1).normal(0, 0.1, (6, 6))
    T = fk(m.robot_, q)
    tcp = se3.make_transform(np.eye(3), np.array([0.0, 0.0, 0.05]))
    prog = (
        "def job():\r\n"
        "  # start: movel(p[0.1,0.2,0.3,0,0,0]) in a comment is not a target\r\n"
        f"  movej([{', '.join(f'{v:.5f}' for v in home)}], a=1.4, v=1.05)\r\n"
        f"  global pt = {_p(T[0])}\r\n"
        "  off = p[0, 0, 0.1, 0, 0, 0]\r\n"
        f"  movel({_p(T[1])}, a=1.2, v=0.25)  # first\r\n"
        "  movel(pose_trans(pt, off), a=1.2, v=0.25)\r\n"
        "  movel(pt, a=1.2, v=0.25)\r\n"
        f"  movec({_p(T[2])},{_p(T[3])}, a=1.2, v=0.1, r=0)\r\n"
        "  textmsg(\"p[1,2,3,4,5,6]\")\r\n"
        "  set_tcp(p[0, 0, 0.05, 0, 0, 0])\r\n"
        f"  movep({_p(T[4] @ tcp)}, a=1.2, v=0.25, r=0.01)\r\n"
        "end\r\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert len(res.targets) == 5 and not res.failed
    assert [t.line for t in res.targets] == [4, 6, 9, 9, 12]
    assert _diff_lines(prog, res.text) == {4, 6, 9, 12}
    assert res.text.count("\r\n") == prog.count("\r\n")
    new, _ = urscript.find_targets(res.text, nom)
    want = np.stack([t.pose for t in res.targets])
    cmd = np.stack([t.pose for t in new])
    D = np.stack([np.eye(4)] * 4 + [tcp])
    # stand-in UR controller: IK of the flange-TCP pose nearest the current joints, in program order
    cur, got = home, []
    for Tc, Dk in zip(cmd, D):
        r = ik(nom, Tc[None] @ se3.invert(Dk), all_branches=True).nearest_to(cur, nom.lower, nom.upper)
        cur = r.q[0]
        got.append(real_tcp(m, fk(m.robot_, cur[None])[0], Dk))
    err = se3.pose_error(np.stack(got), want)
    assert err[0].max() < 2e-3 and err[1].max() < 1e-5  # written with 0.1 µm / 1e-8 rad
    assert se3.pose_error(fk(m.robot_, q[:4]), want[:4])[0].max() < 2e-3  # the walk kept the program's branch


def test_krl_src_and_dat_rewrite():
    m = exact("kuka-kr6-r900", 12)
    nom = m.nominal
    q = nom.random_joints(4, 3, margin=0.2)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    T = fk(m.robot_, q)
    S, Tt = kuka_status(nom, q)
    abc = [krl.abc_from_matrix(Tk[:3, :3]) for Tk in T]

    def agg(k, sep=", "):
        x, y, z = T[k, :3, 3] * 1e3
        return sep.join([f"X {x:.4f}", f"Y {y:.4f}", f"Z {z:.4f}", f"A {abc[k][0]:.5f}", f"B {abc[k][1]:.5f}", f"C {abc[k][2]:.5f}"])

    src = (
        "&ACCESS RVP\r\nDEF job( )\r\n; {X 1, Y 2, Z 3, A 0, B 0, C 0} in a comment\r\n"
        "PTP {A1 0, A2 -90, A3 90, A4 0, A5 45, A6 0}\r\n"
        f"PTP {{E6POS: {agg(0)}, S {S[0]}, T {Tt[0]}, E1 0.0}} C_PTP\r\n"
        "LIN XP1\r\nLIN_REL {X 10}\r\nLIN {Z 400}\r\n"
        f"LIN {{{agg(1)}, S 'B{S[1]:03b}', T 'B{Tt[1]:06b}'}}\r\n"
        "$BASE = BASE_DATA[1]\r\n$TOOL = {X 0.0, Y 0.0, Z 100.0, A 0.0, B 0.0, C 0.0}\r\nCIRC XP2, XP3\r\nEND\r\n"
    )
    dat = (
        "&ACCESS RVP\r\nDEFDAT job\r\n"
        f"DECL E6POS XP1={{{agg(2, ',')},S {S[2]},T {Tt[2]},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}\r\n"
        "DECL FRAME TOOL_OFS={X 0.0,Y 0.0,Z 120.0,A 0.0,B 0.0,C 0.0}\r\n"
        f"DECL POS XP2={{{agg(3, ',')}}}\r\n"
        f"DECL FRAME XP3={{{agg(3, ',')}}}\r\n"
        "ENDDAT\r\n"
    )
    rs = compensate_program(m, src, krl, frame="measurement")
    # XP2 and XP3 are moved to in base 1 with the $TOOL aggregate: without BASE_DATA[1] ($config.dat)
    # their pose is unknown and they fail, saying so; with it (the identity here) they are solved
    r0 = compensate_program(m, dat, krl, frame="measurement", context=src)
    assert [line for line, _ in r0.failed] == [5, 6] and all("BASE_DATA[1]) is not declared" in r for _, r in r0.failed)
    config = "DEFDAT $CONFIG\r\nBASE_DATA[1]={X 0.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}\r\nENDDAT\r\n"
    rd = compensate_program(m, dat, krl, frame="measurement", context=src + config)
    assert len(rs.targets) == 2 and len(rd.targets) == 3 and not rs.failed and not rd.failed
    tool = se3.make_transform(np.eye(3), np.array([0.0, 0.0, 0.1]))
    assert rd.targets[0].tool_delta is None and rd.targets[0].frame is None  # XP1: before the selections
    for t in rd.targets[1:]:
        assert np.allclose(t.frame, np.eye(4)) and np.allclose(t.tool_delta, se3.invert(nom.tool) @ tool)
    assert _diff_lines(src, rs.text) == {5, 9} and _diff_lines(dat, rd.text) == {3, 5, 6}
    assert "E1 0.0} C_PTP\r\n" in rs.text and "S 'B" in rs.text.split("\r\n")[8]
    assert len(rs.notes) == 3  # LIN_REL, the partial aggregate and $TOOL are kept and noted
    assert any("TOOL_OFS" in n for n in rd.notes)
    new = krl.find_targets(rs.text, nom)[0] + krl.find_targets(rd.text, nom, context=src + config)[0]
    want = np.stack([t.pose for t in rs.targets + rd.targets])
    cmd = np.stack([t.pose for t in new])
    # stand-in KUKA controller for the targets with S/T: the nominal solution with exactly those bits
    st = [k for k, t in enumerate(new) if "S" in t.config]
    qc = match_kuka_status(nom, cmd[st], [new[k].config["S"] for k in st], [new[k].config["T"] for k in st])
    assert not np.isnan(qc).any()
    assert se3.pose_error(fk(m.robot_, qc), want[st])[0].max() < 2e-3
    S2, T2 = kuka_status(nom, qc)
    assert list(S2) == [new[k].config["S"] for k in st] and list(T2) == [new[k].config["T"] for k in st]


def test_abc_is_intrinsic_zyx():
    rng = np.random.default_rng(0)
    for abc in rng.uniform([-180, -89, -180], [180, 89, 180], (20, 3)):
        R = Rotation.from_euler("ZYX", abc, degrees=True).as_matrix()
        assert np.allclose(krl.matrix_from_abc(*abc), R, atol=1e-12)
        assert np.allclose(krl.abc_from_matrix(R), abc, atol=1e-9)
    R = Rotation.from_euler("ZYX", [30, 90, 10], degrees=True).as_matrix()  # gimbal lock: A from the hint
    a, b, c = krl.abc_from_matrix(R, 30.0)
    assert np.allclose(krl.matrix_from_abc(a, b, c), R, atol=1e-9) and abs(a - 30) < 1e-9


def test_rapid_rewrite():
    m = exact("abb-irb2400", 13)
    nom = m.nominal
    q = nom.random_joints(3, 5, margin=0.2)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    T = fk(m.robot_, q)
    cf = abb_confdata(nom, q)
    xyz, quat = se3.transform_to_pose(T)

    def rt(k):
        return (f"[[{xyz[k, 0] * 1e3:.3f},{xyz[k, 1] * 1e3:.3f},{xyz[k, 2] * 1e3:.3f}],"
                f"[{quat[k, 0]:.8f},{quat[k, 1]:.8f},{quat[k, 2]:.8f},{quat[k, 3]:.8f}],"
                f"[{cf[k, 0]},{cf[k, 1]},{cf[k, 2]},{cf[k, 3]}],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]")

    mod = (
        "MODULE job\n"
        f"  CONST robtarget p10:={rt(0)}; ! first\n"
        "  PERS tooldata tGrip:=[TRUE,[[0,0,100],[1,0,0,0]],[1,[0,0,1],[1,0,0,0],0,0,0]];\n"
        "  CONST jointtarget jHome:=[[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
        "  ! MoveL [[1,2,3],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]] is a comment\n"
        "  PROC main()\n"
        "    MoveAbsJ jHome, v1000, fine, tool0;\n"
        f"    MoveL {rt(1)}, v100, z10, tool0;\n"
        f"    MoveJ Offs(p10, 0, 0, 100), v1000, fine, tool0;\n"
        f"    VAR robtarget p20 := {rt(2)};\n"
        "  ENDPROC\n"
        "ENDMODULE\n"
    )
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert len(res.targets) == 3 and not res.failed
    assert _diff_lines(mod, res.text) == {2, 8, 10}
    new, _ = rapid.find_targets(res.text, nom)
    cmd = np.stack([t.pose for t in new])
    conf = np.array([t.config["conf"] for t in new])
    qn = np.array([[float(v) for v in t.parts["literal"].split("],[")[1].split(",")] for t in new])
    assert np.allclose(np.linalg.norm(qn, axis=1), 1, atol=2e-9)
    qc = match_abb_confdata(nom, cmd, conf)  # stand-in ABB controller: the solution with that confdata
    assert np.array_equal(abb_confdata(nom, qc), conf)
    want = np.stack([t.pose for t in res.targets])
    assert se3.pose_error(fk(m.robot_, qc), want)[0].max() < 2e-3


def test_unreachable_program_target_is_kept_and_reported():
    m = exact("ur10", 14)
    T = fk(m.robot_, np.array([[0.2, -1.5, 1.6, -1.6, -1.5, 0.3]]))[0]
    far = T.copy()
    far[:3, 3] = [3.0, 0.0, 0.5]
    prog = f"movel({_p(T)}, a=1.2, v=0.25)\nmovel({_p(far)}, a=1.2, v=0.25)\n"
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert len(res.failed) == 1 and res.failed[0][0] == 2
    assert res.text.split("\n")[1] == prog.split("\n")[1] and res.text.split("\n")[0] != prog.split("\n")[0]


def test_bad_rapid_quaternion_is_an_error():
    m = exact("abb-irb2400", 1)
    with pytest.raises(ValueError, match="line 1: robtarget quaternion"):
        compensate_program(m, "CONST robtarget p:=[[1,2,3],[2,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];", rapid)


def test_program_of_a_tracker_frame_model_is_in_the_controller_frame():
    from comp_models import ExactModel, deviate

    from hykin import load_robot

    nom = load_robot("ur10")
    truth = deviate(nom, 15)
    W = se3.make_transform(se3.rotz(-1.1)[:3, :3], np.array([3.0, 1.5, -0.4]))  # tracker 3 m away
    m = ExactModel(nom, truth.copy(base=W @ truth.base))
    q = np.array([0.2, -1.5, 1.6, -1.6, -1.5, 0.3]) + np.random.default_rng(2).normal(0, 0.1, (3, 6))
    T_ctrl = se3.invert(m.robot_.base) @ fk(m.robot_, q)  # wanted poses in the controller (fitted base) frame
    prog = f"movej([{', '.join(f'{v:.6f}' for v in q[0])}])\n" + "".join(f"movel({_p(Tk)}, a=1.2, v=0.25)\n" for Tk in T_ctrl)
    res = compensate_program(m, prog, urscript)  # frame="auto": the fitted base is far -> "base"
    assert res.comp.frame == "base" and not res.failed
    assert compensate(m, T_ctrl, frame="auto").success.all()  # the default walk (from zero) in the right frame
    cmd = np.stack([t.pose for t in urscript.find_targets(res.text, nom)[0]])
    want = np.stack([t.pose for t in res.targets])
    r = ik(nom, cmd, all_branches=True).nearest_to(q, nom.lower, nom.upper)
    real = se3.invert(m.robot_.base) @ fk(m.robot_, r.q)
    assert se3.pose_error(real, want)[0].max() < 2e-3


# ------------------------------------------------------------------------ the stretched elbow (reach edge)


def _stretched_q(nom, n: int, seed: int) -> np.ndarray:
    """``n`` random joints with the elbow 0.05-0.8° from stretched (either side): the reach boundary,
    found by bisection on joint 3 (independent of the matchers: only arm_geometry's sign is used)."""
    from hykin.compensation.branches import arm_geometry

    rng = np.random.default_rng(seed)
    q = nom.random_joints(n, seed, margin=0.3)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    ones = np.ones(nom.dof)
    lo, hi = np.full(n, -np.pi / 2), np.full(n, np.pi / 2)
    for _ in range(60):  # the elbow angle grows with joint 3 through 0 at the stretched pose
        mid = 0.5 * (lo + hi)
        qm = q.copy()
        qm[:, 2] = mid
        pos = arm_geometry(nom, qm, ones)[1] > 0
        hi, lo = np.where(pos, mid, hi), np.where(pos, lo, mid)
    q[:, 2] = 0.5 * (lo + hi) + rng.choice([-1.0, 1.0], n) * np.radians(rng.uniform(0.05, 0.8, n))
    return q


@pytest.mark.parametrize("preset", ["ur5", "rx160", "abb-irb2400"])
def test_abb_forward_side_is_the_nominal_robots_for_its_calibrated_copy(preset):
    """The elbow flag of confdata: "forward" is read off the nominal robot's zero pose. An arm stretched
    at zero (UR, Stäubli) names forward e > 0; a calibrated copy (a fraction of a degree kinked either
    way at zero) must name the same side, or every fallback on it picks the other elbow."""
    from hykin.compensation.branches import arm_geometry

    nom = exact(preset, 0).nominal
    q = nom.random_joints(300, 2, margin=0.1)
    e = arm_geometry(nom, q, np.ones(6))[1]
    q = q[np.abs(e) > np.radians(3)]  # clear of the stretched elbow on every copy
    ref = abb_confdata(nom, q)
    zero = np.clip(np.zeros((1, 6)), nom.lower, nom.upper)
    stretched = abs(arm_geometry(nom, zero, np.ones(6))[1][0]) < 1e-9
    assert stretched == (preset != "abb-irb2400")
    if stretched:  # forward = e > 0
        assert np.array_equal((ref[:, 3] >> 1) & 1, (arm_geometry(nom, q, np.ones(6))[1] < 0).astype(int))
    flipped = 0
    for seed in range(8):
        cal = exact(preset, seed).robot_
        e0 = arm_geometry(cal, np.clip(np.zeros((1, 6)), cal.lower, cal.upper), np.ones(6))[1][0]
        flipped += e0 < 0
        # the elbow bit (the overhead bit has its own singularity, over axis 1, not at issue here)
        assert np.array_equal(abb_confdata(cal, q, reference=nom)[:, 3] & 2, ref[:, 3] & 2)
    if stretched:
        assert 0 < flipped < 8  # the copies' own zero poses disagree: the reference is what makes them agree


def _flags_reached(rob, T, reference=None, kuka=False) -> list:
    """Per pose ``T`` ``(N, 4, 4)`` the set of cfx (or S) values of ``rob``'s solutions within its limits."""
    from hykin.compensation.branches import candidate_solutions

    q, ok = candidate_solutions(rob, T)
    N, K, n = q.shape
    f = (kuka_status(rob, np.nan_to_num(q.reshape(-1, n)))[0] if kuka else
         abb_confdata(rob, np.nan_to_num(q.reshape(-1, n)), reference=reference)[:, 3]).reshape(N, K)
    return [set(f[i][ok[i]].tolist()) for i in range(N)]


@pytest.mark.parametrize("preset,seed", [("ur5", 0), pytest.param("ur5", 4, marks=pytest.mark.slow),
                                         pytest.param("rx160", 1, marks=pytest.mark.slow), ("rx160", 2)])
def test_rapid_targets_at_the_stretched_elbow_keep_their_branch_or_take_the_other_flag_with_a_note(preset, seed):
    """Targets 0.05-0.8° from the stretched elbow, where the real robot (the deviated copy) reaches
    further than the nominal (an ABB arm's axis 3 cannot stretch it within its limits): every one is
    compensated; the stand-in controller (the nominal solution with the confdata written) puts the real
    robot on the target; the flags are the program's unless the real robot has no solution with them
    (then only the elbow / overhead flag differs, noted); with config_slack_deg=0 those fail.
    (rx160 seed 2: a Stäubli arm stretched is also nearly over axis 1, and one target's overhead flag
    differs between the robots.)"""
    m = exact(preset, seed)
    nom = m.nominal
    q = _stretched_q(nom, 30, seed)
    tcp = fk(m.robot_, q)
    cf = abb_confdata(nom, q)
    xyz, quat = se3.transform_to_pose(tcp)
    body = "".join(
        f"    MoveL [[{xyz[k, 0] * 1e3:.6f},{xyz[k, 1] * 1e3:.6f},{xyz[k, 2] * 1e3:.6f}],"
        f"[{quat[k, 0]:.10f},{quat[k, 1]:.10f},{quat[k, 2]:.10f},{quat[k, 3]:.10f}],"
        f"[{cf[k, 0]},{cf[k, 1]},{cf[k, 2]},{cf[k, 3]}],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]], v200, fine, tool0;\n"
        for k in range(len(q)))
    mod = "MODULE edge\n  PROC main()\n" + body + "  ENDPROC\nENDMODULE\n"
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert not res.failed, res.failed
    new, _ = rapid.find_targets(res.text, nom)
    conf = np.array([t.config["conf"] for t in new])
    qc = match_abb_confdata(nom, np.stack([t.pose for t in new]), conf)
    assert not np.isnan(qc).any()
    assert se3.pose_error(fk(m.robot_, qc), tcp)[0].max() < 2e-3
    # the real robot's own flags at the joints it goes to: the program's, except the noted rows, and
    # those only where the real robot has no solution with the program's flags
    own = abb_confdata(m.robot_, qc, reference=nom)
    other = own[:, 3] != cf[:, 3]
    assert np.all((own[other, 3] ^ cf[other, 3]) & ~6 == 0)  # only the overhead / elbow bits
    reached = _flags_reached(m.robot_, np.stack([t.pose for t in res.targets]), reference=nom)
    assert all(cf[k, 3] not in reached[k] for k in np.flatnonzero(other))
    noted = [n for n in res.notes if "singular pose" in n]
    assert bool(other.any()) == bool(noted)
    if other.any():
        assert f"{int(other.sum())} targets" in noted[0]
        strict = compensate_program(m, mod, rapid, frame="measurement", config_slack_deg=0)
        assert len(strict.failed) == int(other.sum())
        assert all("configuration data (cfx " in r and "the real robot reaches it with cfx" in r for _, r in strict.failed)
    with pytest.raises(ValueError, match="config_slack_deg"):
        compensate_program(m, mod, rapid, config_slack_deg=-1)


def test_krl_targets_at_the_stretched_elbow_are_compensated_where_the_real_robot_has_their_status():
    """KUKA's S bits 0 and 1 at the reach boundary: the same fallback as RAPID's flags. A target fails
    only where the real robot has no solution with the program's S (its non-spherical wrist can
    shorten the reach with one wrist flag: checked on its own IK solutions)."""
    m = exact("kuka-kr6-r900", 2)
    nom = m.nominal
    q = _stretched_q(nom, 30, 2)
    tcp = fk(m.robot_, q)
    S, T = kuka_status(nom, q)
    lines = []
    for k in range(len(q)):
        a, b, c = krl.abc_from_matrix(tcp[k, :3, :3])
        x, y, z = tcp[k, :3, 3] * 1e3
        lines.append(f"LIN {{X {x:.5f}, Y {y:.5f}, Z {z:.5f}, A {a:.6f}, B {b:.6f}, C {c:.6f}, S {S[k]}, T {T[k]}}}")
    src = "DEF edge()\n" + "\n".join(lines) + "\nEND\n"
    res = compensate_program(m, src, krl, frame="measurement")
    failed = np.array([line - 2 for line, _ in res.failed], dtype=int)
    reached = _flags_reached(m.robot_, np.stack([t.pose for t in res.targets]), kuka=True)
    assert len(failed) <= 2 and all(S[k] not in reached[k] for k in failed)
    for (_, r), k in zip(res.failed, failed):  # the reason names the S asked for and those the robot has
        assert f"(S {S[k]}); the real robot reaches it with S {', '.join(str(v) for v in sorted(reached[k]))}" in r
    done = np.setdiff1d(np.arange(len(q)), failed)
    new = krl.find_targets(res.text, nom)[0]
    qc = match_kuka_status(nom, np.stack([new[k].pose for k in done]), [new[k].config["S"] for k in done],
                           [new[k].config["T"] for k in done])
    assert not np.isnan(qc).any()
    assert se3.pose_error(fk(m.robot_, qc), tcp[done])[0].max() < 2e-3
    own, _ = kuka_status(m.robot_, qc)
    other = own != S[done]
    assert np.all((own[other] ^ S[done][other]) & ~3 == 0)
    assert bool(other.any()) == any("singular pose" in n for n in res.notes)
