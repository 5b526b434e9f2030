"""KRL targets taken where and how the ``.src`` uses them.

Each program here is built from a deviated truth robot (``comp_models.exact``: the model's prediction
is the truth): the targets are where the truth robot's program TCP is at chosen joints. After
compensation a stand-in KUKA controller executes the written program with the NOMINAL model, in
execution order: ``PTP`` joint moves set the joints; a target with ``S``/``T`` takes the nominal solution
with exactly those; one without the nominal solution nearest the joints the robot is at (a LIN/CIRC
step that the test marks "cp": nearest among those with the status S the robot is in); each in the
base and with the tool the program selects there (``W · literal [· R] · inv(D)``). The truth robot at
those joints must put the program's TCP on the wanted pose (2e-3 mm).
"""

from __future__ import annotations

import re

import numpy as np
from cli_run import run
from comp_models import exact, real_tcp

from hykin import fk
from hykin.compensation import krl
from hykin.compensation.branches import default_axis_signs, kuka_status, match_kuka_status
from hykin.compensation.programs import compensate_program
from hykin.geometry import se3
from hykin.kinematics.ik import ik


def _xyzabc(T) -> str:
    a, b, c = krl.abc_from_matrix(T[:3, :3])
    x, y, z = T[:3, 3] * 1e3
    return f"X {x:.6f},Y {y:.6f},Z {z:.6f},A {a:.8f},B {b:.8f},C {c:.8f}"


def _frame(x, y, z, a, b, c) -> np.ndarray:
    """A KRL frame (mm, deg) as (4, 4) (m)."""
    return se3.make_transform(krl.matrix_from_abc(a, b, c), np.array([x, y, z]) * 1e-3)


def _q(nom, deg) -> np.ndarray:
    """hykin joints (rad) of controller axis angles (deg)."""
    return default_axis_signs(nom) * np.radians(np.asarray(deg, dtype=float))


def _axes(nom, q) -> str:
    a = np.degrees(q / default_axis_signs(nom))
    return ", ".join(f"A{i + 1} {v:.6f}" for i, v in enumerate(a))


def _status(nom, q) -> str:
    S, T = kuka_status(nom, q[None])
    return f"S {int(S[0])},T {int(T[0])}"


def _controller(m, steps) -> list:
    """Joints of a stand-in KUKA controller (nominal model) per ``("pose", flange (4, 4), config)`` step of
    ``steps`` (``("joint", q)`` steps move there): the solution with the config's S/T where it has them,
    else the one nearest the joints the robot is at; a ``"cp"`` step (LIN/CIRC without S) keeps the
    status S the robot is in (nearest among those)."""
    nom = m.nominal
    cur, out = np.clip(np.zeros(nom.dof), nom.lower, nom.upper), []
    for kind, value, *cfg in steps:
        if kind == "joint":
            cur = value
            continue
        if cfg and "S" in cfg[0]:
            cur = match_kuka_status(nom, value[None], [cfg[0]["S"]], [cfg[0]["T"]])[0]
        elif kind == "cp":
            sols = ik(nom, value[None], all_branches=True)
            qz = np.nan_to_num(sols.q[0])
            same = sols.success[0] & (kuka_status(nom, qz)[0] == kuka_status(nom, cur[None])[0][0])
            cur = qz[int(np.argmin(np.where(same, np.linalg.norm(qz - cur, axis=1), np.inf)))]
        else:
            cur = ik(nom, value[None], all_branches=True).nearest_to(cur, nom.lower, nom.upper).q[0]
        out.append(cur)
    return out


def _lit(text: str, line: int) -> tuple:
    """``(pose (4, 4) m, {"S", "T"} or {})`` of the Cartesian aggregate on ``line`` (1-based) of ``text``,
    read here (not by hykin's parser): the literal as the controller reads it."""
    body = next(b for b in re.findall(r"\{([^{}]*)\}", text.split("\n")[line - 1]) if re.search(r"\bX\s", b))
    v = {k.upper(): t for k, t in re.findall(r"\b([XYZABCST])\s+('B[01]+'|[-+\d.eE]+)", body)}
    num = lambda t: int(t[2:-1], 2) if t.startswith("'") else float(t)
    pose = _frame(*(num(v[k]) for k in "XYZABC"))
    return pose, ({"S": int(num(v["S"])), "T": int(num(v["T"]))} if "S" in v else {})


def _landed_mm(m, qs, Ds, want) -> np.ndarray:
    """Position error (mm) of the truth robot's program TCP ``fk · D`` at ``qs`` from ``want``."""
    got = np.stack([real_tcp(m, fk(m.robot_, q[None])[0], D) for q, D in zip(qs, Ds)])
    return np.linalg.norm(got[:, :3, 3] - np.asarray(want)[:, :3, 3], axis=1) * 1e3


def _diff(a: str, b: str) -> set:
    la, lb = a.split("\n"), b.split("\n")
    assert len(la) == len(lb)
    return {i for i, (x, y) in enumerate(zip(la, lb), 1) if x != y}


# D1: a .dat point without S/T is walked where the .src moves to it -----------------------------------

def test_dat_points_without_status_are_walked_in_the_order_the_src_moves_to_them():
    """``PTP XHOME`` (E6AXIS in $config.dat), ``PTP XP1`` (S/T), ``LIN P2`` (no S/T, declared before XP1
    in the .dat), ``PTP XHOME2``, ``LIN P3`` (no S/T): P2's branch is the one nearest XP1's joints, P3's
    the one nearest XHOME2's (the joint move restarts the walk), not those of the declaration order."""
    m = exact("kuka-kr6-r900", 7)
    nom = m.nominal
    q1 = _q(nom, [-15, -85, 95, 25, -40, 55])
    q2 = _q(nom, [-14.7, -90, 100.3, 30, -45.3, 59.7])  # elbow up, wrist flipped: far from zero
    qh2 = _q(nom, [5, -80, 95, -55, 25, -55])
    q3 = _q(nom, [8, -78, 92, -60, 20, -60])  # nearest XHOME2's wrist; the flipped wrist is nearer q1's
    tcp = fk(m.robot_, np.stack([q1, q2, q3]))
    dat = ("DEFDAT lin3\r\n"
           f"DECL POS P2={{{_xyzabc(tcp[1])}}}\r\n"
           f"DECL E6POS XP1={{{_xyzabc(tcp[0])},{_status(nom, q1)},E1 0.0,E2 0.0}}\r\n"
           f"DECL POS P3={{{_xyzabc(tcp[2])}}}\r\n"
           f"DECL POS P9={{{_xyzabc(tcp[2])}}}\r\n"  # moved to by no motion of the .src
           "ENDDAT\r\n")
    src = ("DEF lin3( )\r\n  BAS(#INITMOV, 0)\r\n  PTP XHOME\r\n  PTP XP1\r\n  LIN P2 C_DIS\r\n"
           "  PTP XHOME2\r\n  LIN P3\r\nEND\r\n")
    config = (f"DEFDAT $CONFIG\r\nDECL E6AXIS XHOME={{{_axes(nom, _q(nom, [0, -90, 90, 0, 0, 0]))},E1 0.0}}\r\n"
              f"DECL E6AXIS XHOME2={{{_axes(nom, qh2)}}}\r\nENDDAT\r\n")
    res = compensate_program(m, dat, krl, frame="measurement", context=src + config)
    assert not res.failed and len(res.targets) == 4
    assert _diff(dat, res.text) == {2, 3, 4, 5}
    xp1, p2, p3 = (_lit(res.text, line) for line in (3, 2, 4))
    steps = [("joint", _q(nom, [0, -90, 90, 0, 0, 0])), ("pose", *xp1), ("pose", *p2), ("joint", qh2), ("pose", *p3)]
    qs = _controller(m, steps)
    err = _landed_mm(m, qs, [np.eye(4)] * 3, tcp)
    assert err.max() < 2e-3, err
    # the walk kept the program's branches: the controller is where the truth joints are
    assert np.abs(np.stack(qs) - np.stack([q1, q2, q3])).max() < np.radians(2)
    order = {t.name: t.order for t in res.targets}
    assert all(isinstance(v, int) for v in order.values())
    assert order["XP1"] < order["P2"] < order["P3"] < order["P9"]  # executed order; the unused one last
    resets = {t.name: t.reset for t in res.targets}
    assert resets["P2"] is None and np.allclose(resets["P3"], qh2) and resets["P9"] is None


def test_src_variable_is_walked_where_it_is_moved_to():
    """``DECL POS pC = {..}`` at the top of an expert .src, moved to at the end by a LIN after a joint
    move and an inline target: its branch keeps the status of the joint move before it."""
    m = exact("kuka-kr6-r900", 9)
    nom = m.nominal
    qj = _q(nom, [10, -80, 95, 20, 40, -30])
    qa = _q(nom, [12, -82, 97, 25, 35, -25])
    qc = _q(nom, [-14.7, -90, 100.3, 30, -45.3, 59.7])
    tcp = fk(m.robot_, np.stack([qa, qc]))
    src = ("DEF expert( )\n"
           f"  DECL POS pC = {{{_xyzabc(tcp[1])}}}\n"
           "  BAS(#INITMOV, 0)\n"
           f"  PTP {{{_axes(nom, qj)}}}\n"
           f"  LIN {{{_xyzabc(tcp[0])}}} C_DIS   ; untyped, walked\n"
           f"  PTP {{{_axes(nom, qa)}}}\n"
           "  LIN pC\n"
           "END\n")
    res = compensate_program(m, src, krl, frame="measurement")
    assert not res.failed and [t.line for t in res.targets] == [2, 5]
    assert _diff(src, res.text) == {2, 5}
    qs = _controller(m, [("joint", qj), ("cp", *_lit(res.text, 5)), ("joint", qa), ("cp", *_lit(res.text, 2))])
    err = _landed_mm(m, qs, [np.eye(4)] * 2, tcp)
    assert err.max() < 2e-3, err
    pc, inline = res.targets
    assert inline.order < pc.order and np.allclose(pc.reset, qa) and np.allclose(inline.reset, qj)


# D4: spline motions and their WITH clauses ---------------------------------------------------------

B1 = _frame(600.0, -200.0, 50.0, 90.0, 0.0, 0.0)
B2 = _frame(-150.0, 420.0, 80.0, -35.0, 4.0, 2.0)
TL1 = _frame(10.0, 0.0, 150.0, 0.0, 0.0, 0.0)
TL2 = _frame(-5.0, 12.0, 120.0, 0.0, 20.0, 0.0)

_CONFIG = ("DEFDAT $CONFIG PUBLIC\r\nDECL FRAME BASE_DATA[32]\r\n"
           f"BASE_DATA[1]={{{_xyzabc(B1)}}}\r\nBASE_DATA[2]={{{_xyzabc(B2)}}}\r\n"
           f"DECL FRAME TOOL_DATA[16]\r\nTOOL_DATA[1]={{{_xyzabc(TL1)}}}\r\nTOOL_DATA[2]={{{_xyzabc(TL2)}}}\r\n"
           "DECL E6AXIS XHOME={A1 0.0,A2 -90.0,A3 90.0,A4 0.0,A5 0.0,A6 0.0,E1 0.0}\r\n"
           'DECL FDAT FHOME={TOOL_NO 0,BASE_NO 0,IPO_FRAME #BASE,POINT2[] " "}\r\nENDDAT\r\n')


def _with(fp: str) -> str:
    return (f" WITH $TOOL = STOOL2({fp}), $BASE = SBASE({fp}.BASE_NO), $IPO_MODE = SIPO_MODE({fp}.IPO_FRAME), "
            f"$LOAD = SLOAD({fp}.TOOL_NO), $ACC = SACC(LCPDAT1), $VEL = SVEL_CP(0.2, , LCPDAT1), "
            "$COLLMON_TOL_PRO[1] = USE_CM_PRO_VALUES(0)")


def _spline_program(m, q):
    """(.src, .dat, wanted TCP poses, their (W, D)) of a spline inline-form program: SPTP/SLIN with WITH
    clauses naming FDATs, a SPLINE block with its own WITH and a segment's, an SCIRC, an inline SPL."""
    nom = m.nominal
    D1, D2 = se3.invert(nom.tool) @ TL1, se3.invert(nom.tool) @ TL2
    frames = [(B1, D1), (B2, D2), (B2, D1), (B2, D2), (B2, D1), (B2, D1), (B2, D1)]
    tcp = np.stack([real_tcp(m, fk(m.robot_, q[k:k + 1])[0], frames[k][1]) for k in range(len(frames))])
    lit = [se3.invert(W) @ T for (W, _), T in zip(frames, tcp)]
    st = [_status(nom, q[k]) for k in range(len(frames))]
    dat = "DEFDAT spl\r\n" + "".join(
        f"DECL E6POS XP{k + 1}={{{_xyzabc(lit[k])},{st[k]},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}\r\n"
        for k in range(6))
    dat += ('DECL FDAT FP1={TOOL_NO 1,BASE_NO 1,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}\r\n'
            'DECL FDAT FP2={TOOL_NO 2,BASE_NO 2,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}\r\n'
            'DECL FDAT FP5={TOOL_NO 1,BASE_NO 2,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}\r\nENDDAT\r\n')
    src = ("DEF spl( )\r\nBAS (#INITMOV,0 )\r\n"
           ";FOLD SPTP HOME Vel=100 % DEFAULT ;%{PE}\r\n"
           "SPTP XHOME WITH $VEL_AXIS[1] = SVEL_JOINT(100.0), $TOOL = STOOL2(FHOME), $BASE = SBASE(FHOME.BASE_NO), "
           "$IPO_MODE = SIPO_MODE(FHOME.IPO_FRAME), $LOAD = SLOAD(FHOME.TOOL_NO)\r\n;ENDFOLD\r\n"
           f";FOLD SPTP P1 Vel=100 % PDAT1 Tool[1] Base[1] ;%{{PE}}\r\nSPTP XP1{_with('FP1')}\r\n;ENDFOLD\r\n"
           f"SLIN XP2{_with('FP2')}\r\n"
           "SPLINE WITH $BASE = BASE_DATA[2], $TOOL = TOOL_DATA[1], $VEL = SVEL_CP(0.2, , LCPDAT1)\r\n"
           "  SPL XP3\r\n  SLIN XP4 WITH $TOOL = TOOL_DATA[2]\r\n"
           f"  SPL {{E6POS: {_xyzabc(lit[6])}, {st[6].replace(',', ', ')}}}\r\n"
           "ENDSPLINE\r\n"
           f"SCIRC XP5, XP6, CA 90.0 C_SPL{_with('FP5')}\r\n"
           "END\r\n")
    return src, dat, tcp, frames


def test_spline_motions_take_the_base_and_tool_of_their_with_clauses():
    m = exact("kuka-kr6-r900", 12)
    nom = m.nominal
    q = nom.random_joints(7, 5, margin=0.25)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    src, dat, tcp, frames = _spline_program(m, q)
    rd = compensate_program(m, dat, krl, frame="measurement", context=src + _CONFIG)
    rs = compensate_program(m, src, krl, frame="measurement", context=dat + _CONFIG)
    assert not rd.failed and not rs.failed and len(rd.targets) == 6 and len(rs.targets) == 1
    for t, (W, D) in zip(rd.targets + rs.targets, frames):
        assert np.allclose(t.frame, W) and np.allclose(t.tool_delta, D), t.name
    assert np.abs(np.stack([t.pose for t in rd.targets + rs.targets]) - tcp).max() < 1e-8
    assert _diff(dat, rd.text) == set(range(2, 8)) and _diff(src, rs.text) == {13}
    assert not any("cannot evaluate" in n for n in rd.notes + rs.notes)
    lits = [_lit(rd.text, line) for line in range(2, 8)] + [_lit(rs.text, 13)]
    steps = [("pose", W @ P @ se3.invert(D), cfg) for (P, cfg), (W, D) in zip(lits, frames)]
    qs = _controller(m, steps)
    err = _landed_mm(m, qs, [D for _, D in frames], tcp)
    assert err.max() < 2e-3, err


def test_spline_selections_hykin_cannot_resolve_fail_their_targets():
    """An index expression, an external TCP, an FDAT not read, and a plain motion after WITH motions
    (whether a WITH selection outlasts its motion is not taken for granted): those targets fail with
    the reason; the others are compensated."""
    m = exact("kuka-kr6-r900", 12)
    nom = m.nominal
    q = nom.random_joints(7, 5, margin=0.25)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    src, dat, _, _ = _spline_program(m, q)
    src = (src.replace("$BASE = SBASE(FP2.BASE_NO)", "$BASE = SBASE(nBase)")
           .replace("SPTP XP1 WITH $TOOL = STOOL2(FP1)", "SPTP XP1 WITH $TOOL = STOOL2(FP9)")
           .replace("END\r\n", "SLIN XP6\r\nEND\r\n")
           .replace("SCIRC XP5, XP6", "SCIRC XP5, XP7"))
    xp7 = f"DECL E6POS XP7={{{_xyzabc(fk(nom, q[6:7])[0])},{_status(nom, q[6])}}}\r\n"
    dat = dat.replace("ENDDAT", xp7 + "ENDDAT")
    dat = dat.replace("FP5={TOOL_NO 1,BASE_NO 2,IPO_FRAME #BASE", "FP5={TOOL_NO 1,BASE_NO 2,IPO_FRAME #TCP")
    res = compensate_program(m, dat, krl, frame="measurement", context=src + _CONFIG)
    why = {t.name: t.error for t in res.targets if t.error}
    assert set(why) == {"XP1", "XP2", "XP5", "XP6", "XP7"}, res.failed
    assert sorted(line for line, _ in res.failed) == sorted(t.line for t in res.targets if t.error)
    assert "FP9: its FDAT declaration (the .dat) was not read" in why["XP1"]
    assert "nBase" in why["XP2"] and "cannot evaluate" in why["XP2"]
    assert "external TCP" in why["XP5"] and "external TCP" in why["XP7"]
    assert "outlasts its motion" in why["XP6"]
    assert res.comp.success.tolist() == [False, False, True, True, False, False, False]


# D6: FRAME variables declared on one line and assigned on another --------------------------------

def test_frame_variables_are_tool_base_and_offset_not_targets():
    """``DECL FRAME fTool, fOffs`` ... ``fTool = {..}`` ... ``$TOOL = fTool``, ``$BASE = fBase``, ``LIN pA :
    fOffs``: the FRAME aggregates are kept (noted), the targets are taken with that tool in that base,
    and pA moved to through the offset lands where ``fBase · pA · fOffs`` puts the TCP."""
    m = exact("kuka-kr6-r900", 3)
    nom = m.nominal
    q = nom.random_joints(2, 11, margin=0.25)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    fTool, fOffs, fBase = _frame(10, 0, 150, 0, 0, 0), _frame(0, 0, -50, 0, 0, 10), _frame(600, -200, 50, 90, 0, 0)
    D = se3.invert(nom.tool) @ fTool
    tcp = real_tcp(m, fk(m.robot_, q), D)
    lit = [se3.invert(fBase) @ tcp[0], se3.invert(fBase) @ tcp[1] @ se3.invert(fOffs)]
    src = ("DEF t( )\n  DECL FRAME fTool, fOffs\n  DECL FRAME fBase\n  DECL E6POS pA\n  BAS(#INITMOV, 0)\n"
           f"  fTool = {{{_xyzabc(fTool)}}}\n  fOffs = {{{_xyzabc(fOffs)}}}\n  fBase = {{{_xyzabc(fBase)}}}\n"
           "  $TOOL = fTool\n  $BASE = fBase\n  PTP {A1 0, A2 -90, A3 90, A4 0, A5 30, A6 0}\n"
           f"  LIN {{{_xyzabc(lit[0])}, {_status(nom, q[0])}}}\n"
           f"  pA = {{E6POS: {_xyzabc(lit[1])}, {_status(nom, q[1])}}}\n"
           "  LIN pA : fOffs\nEND\n")
    res = compensate_program(m, src, krl, frame="measurement")
    assert not res.failed and [t.line for t in res.targets] == [12, 13]
    assert _diff(src, res.text) == {12, 13}
    assert sum(("FRAME fTool" in n or "FRAME fOffs" in n or "FRAME fBase" in n) for n in res.notes) == 3
    lits = [_lit(res.text, line) for line in (12, 13)]
    steps = [("pose", fBase @ P @ R @ se3.invert(D), cfg) for (P, cfg), R in zip(lits, [np.eye(4), fOffs])]
    err = _landed_mm(m, _controller(m, steps), [D, D], tcp)
    assert err.max() < 2e-3, err
    # a FRAME variable without a value hykin can read: the targets after it fail, saying so
    bad = src.replace("DECL FRAME fBase\n", "DECL FRAME fBase, fOther\n").replace("$TOOL = fTool", "$TOOL = fOther")
    rb = compensate_program(m, bad, krl, frame="measurement")
    assert len(rb.failed) == 2 and all("FRAME fOther" in r for _, r in rb.failed), rb.failed


# D7: a .src whose points are all in its .dat -----------------------------------------------------

def test_cli_src_without_own_targets_is_copied_unchanged(tmp_path, capsys):
    from comp_models import tiny_model_file

    model = tiny_model_file()
    src = tmp_path / "job.src"
    src.write_bytes(b"&ACCESS RVP\r\nDEF job( )\r\nPTP XP1\r\nLIN XP2 ; {X 1, Y 2, Z 3, A 0, B 0, C 0}\r\nEND\r\n")
    (tmp_path / "job.dat").write_bytes(
        b"DEFDAT job\r\nDECL E6POS XP1={X 700.0,Y 100.0,Z 600.0,A 0.0,B 90.0,C 0.0}\r\n"
        b"DECL POS XP2={X 650.0,Y 150.0,Z 550.0,A 0.0,B 90.0,C 0.0}\r\nENDDAT\r\n")
    out = tmp_path / "job_out.src"
    code, _, err = run(["compensate", model, src, "-o", out], capsys)
    assert code == 0, err
    assert out.read_bytes() == src.read_bytes()
    assert "job.dat" in err and "unchanged" in err
    # no companion .dat: nothing to say about, still refused
    lone = tmp_path / "lone.src"
    lone.write_bytes(src.read_bytes())
    code, _, err = run(["compensate", model, lone, "-o", tmp_path / "lone_out.src"], capsys)
    assert code != 0 and "no Cartesian targets found" in err and not (tmp_path / "lone_out.src").exists()


def test_a_lin_without_status_keeps_the_configuration_the_robot_is_in():
    """KSS ignores S/T on continuous-path motions: a LIN keeps the arm's status S. From a PTP with A5 just
    below 0 (S bit 2 set) and A4/A6 80° off the target's, a LIN to a POS without S/T is reached on the
    flipped wrist (A5 < 0), though the solution nearest in joint space has A5 > 0: hykin must solve that
    branch (the nearest one would make the real robot land mm off). The stand-in controller here keeps S."""
    m = exact("kuka-kr6-r900", 31)
    nom = m.nominal
    A_t = np.array([20.0, -80.0, 95.0, 30.0, 1.0, 40.0])  # the target's joints, A5 > 0
    A_c = np.array([20.0, -80.0, 95.0, 110.0, -0.5, 120.0])  # where the PTP leaves the robot, A5 < 0
    q_t, q_c = _q(nom, A_t), _q(nom, A_c)
    want = fk(m.robot_, q_t[None])[0]  # the truth robot's TCP at the target joints
    src = f"DEF t()\nPTP {{{_axes(nom, q_c)}}}\nLIN {{{_xyzabc(want)}}}\nEND\n"
    res = compensate_program(m, src, krl, frame="measurement")
    assert not res.failed and res.targets[0].config.get("keep_status")
    pose, _ = _lit(res.text, 3)
    sols = ik(nom, pose[None], all_branches=True)
    S_c = kuka_status(nom, q_c[None])[0][0]
    ok = sols.success[0] & (kuka_status(nom, np.nan_to_num(sols.q[0]))[0] == S_c)
    d = np.where(ok, np.linalg.norm(np.nan_to_num(sols.q[0]) - q_c, axis=1), np.inf)
    q_ctrl = sols.q[0][int(np.argmin(d))]  # the controller: same S, nearest
    assert (q_ctrl[4] * default_axis_signs(nom)[4]) < 0  # the flipped wrist
    assert _landed_mm(m, [q_ctrl], [np.eye(4)], [want])[0] < 2e-3
    # the joint-space nearest solution (what the walk took before) is the other wrist
    near = ik(nom, pose[None], all_branches=True).nearest_to(q_c, nom.lower, nom.upper).q[0]
    assert kuka_status(nom, near[None])[0][0] != S_c
