"""Program frames: a RAPID robtarget is a pose of the instruction's tool in its work object, a KRL
aggregate a pose of ``$TOOL`` in ``$BASE``.

The stand-in controllers here know the declared frames: they move the flange to
``W · literal · inv(tool)`` on the program's confdata / S and T with the nominal model. The real robot (the
model's calibrated chain) must then put the program's TCP on the wanted pose in the base frame.
Frames the program does not define fail the target, with the reason, and nothing is guessed.
"""

from __future__ import annotations

import numpy as np
import pytest
from cli_run import run
from comp_models import exact, real_tcp

from hykin import fk
from hykin.compensation import krl, rapid
from hykin.compensation.branches import abb_confdata, kuka_status, match_abb_confdata, match_kuka_status
from hykin.compensation.programs import compensate_program
from hykin.geometry import se3


def _frame(xyz_mm, quat) -> np.ndarray:
    q = np.asarray(quat, dtype=float)
    return se3.pose_to_transform(np.asarray(xyz_mm, dtype=float) * 1e-3, q / np.linalg.norm(q))


def _f(T) -> str:
    xyz, quat = se3.transform_to_pose(T[None])
    return ("[[" + ",".join(f"{v:.6f}" for v in xyz[0] * 1e3) + "],[" + ",".join(f"{v:.10f}" for v in quat[0]) + "]]")


def _robt(T, cf) -> str:
    return _f(T)[:-1] + ",[" + ",".join(str(int(c)) for c in cf) + "],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]"


UF = _frame([850.0, -420.0, 310.0], [0.9659258, 0.0, 0.0, 0.2588190])  # 30 deg about z
OF = _frame([25.0, 40.0, -5.0], [0.9961947, 0.0871557, 0.0, 0.0])  # 10 deg about x
TF = _frame([12.0, -8.0, 145.0], [0.9848078, 0.0, 0.1736482, 0.0])  # 20 deg about y


@pytest.fixture(scope="module")
def setup():
    m = exact("abb-irb2400", 13)
    nom = m.nominal
    q = nom.random_joints(4, 21, margin=0.25)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    D = se3.invert(nom.tool) @ TF  # the program's TCP relative to the robot file's tool
    W = UF @ OF
    tcp = real_tcp(m, fk(m.robot_, q), D)  # where the real robot's program TCP is at q (base frame)
    return m, q, D, W, tcp, abb_confdata(nom, q)


def _module(tcp, W, cf, wobj_decl=True, tool_decl=True) -> str:
    loc = se3.invert(W) @ tcp
    decl = ""
    if tool_decl:
        decl += "  PERS tooldata tGun:=[TRUE," + _f(TF) + ",[2.5,[0,0,80],[1,0,0,0],0,0,0]];\n"
    if wobj_decl:
        decl += "  TASK PERS wobjdata wTable:=[FALSE,TRUE,\"\"," + _f(UF) + "," + _f(OF) + "];\n"
    return (
        "MODULE cell\n" + decl
        + f"  CONST robtarget pA:={_robt(loc[0], cf[0])};\n"
        + f"  CONST robtarget path{{2}}:=[{_robt(loc[1], cf[1])},\n      {_robt(loc[2], cf[2])}];\n"
        + "  PROC main()\n"
        + "    MoveJ pA, v1000, z50, tGun\\WObj:=wTable;\n"
        + "    MoveL path{1}, v500 \\T:=2, fine, tGun \\WObj:=wTable;\n"
        + "    MoveL Offs(path{2}, 0, 0, 0),\n        v500, z10, tGun\\WObj:=wTable;\n"
        + f"    MoveL {_robt(tcp[3], cf[3])}, v200, fine, tool0;\n"
        + "  ENDPROC\n"
        + "ENDMODULE\n"
    )


def _controller_lands(m, res, setup_W) -> np.ndarray:
    """Position error (mm) of the real robot's program TCP after the stand-in controller executes the
    rewritten literals: the first three in wTable with tGun, the last in the base frame with tool0."""
    new, _ = rapid.find_targets(res.text, m.nominal)
    nom = m.nominal
    local = [se3.invert(t.frame) @ t.pose if t.frame is not None else t.pose for t in new]
    W = [setup_W, setup_W, setup_W, np.eye(4)]
    D = se3.invert(nom.tool) @ TF
    Ds = [D, D, D, np.eye(4)]
    flange_tcp = np.stack([W[k] @ local[k] @ se3.invert(Ds[k]) for k in range(4)])  # nominal-tool TCP wanted
    conf = np.array([t.config["conf"] for t in new])
    qc = match_abb_confdata(nom, flange_tcp, conf)
    return np.stack([real_tcp(m, fk(m.robot_, qc[k:k + 1])[0], Ds[k]) for k in range(4)])


def test_work_object_and_tool_are_applied_and_written_back_in_the_work_object(setup):
    m, q, D, W, tcp, cf = setup
    mod = _module(tcp, W, cf)
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert len(res.targets) == 4 and not res.failed, res.failed
    for t in res.targets[:3]:
        assert np.allclose(t.frame, W) and np.allclose(t.tool_delta, D)
    assert res.targets[3].frame is None and res.targets[3].tool_delta is None
    # the poses found are the wanted TCP poses in the base frame
    assert np.abs(np.stack([t.pose for t in res.targets]) - tcp).max() < 1e-8
    got = _controller_lands(m, res, W)
    err_mm = np.linalg.norm(got[:, :3, 3] - tcp[:, :3, 3], axis=1) * 1e3
    assert err_mm.max() < 2e-3, err_mm
    # the uncompensated program misses by the model's error: the rewrite changed the literals
    assert res.text != mod and res.comp.shift_mm.min() > 0.1


def test_same_targets_without_frames_would_land_elsewhere(setup):
    """The reference the frames matter for: reading the wTable literals in the base frame puts the
    TCP hundreds of mm away (what hykin did before it read work objects)."""
    m, q, D, W, tcp, cf = setup
    loc = se3.invert(W) @ tcp
    assert np.linalg.norm(loc[:3, :3, 3] - tcp[:3, :3, 3], axis=1).min() > 0.3


def test_undeclared_work_object_fails_its_targets_with_the_reason(setup):
    m, q, D, W, tcp, cf = setup
    mod = _module(tcp, W, cf, wobj_decl=False)
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert [line for line, _ in res.failed] == [t.line for t in res.targets[:3]]
    assert all("work object wTable is not declared" in r and "--context" in r for _, r in res.failed)
    assert res.comp.success.tolist() == [False, False, False, True]
    # its literals stay as they were; the tool0 target is rewritten
    assert _module(tcp, W, cf, wobj_decl=False).split("MoveL [[")[0] == res.text.split("MoveL [[")[0]


def test_context_module_declares_the_frames(setup):
    m, q, D, W, tcp, cf = setup
    full = _module(tcp, W, cf)
    decl = "\n".join(line for line in full.splitlines() if "tooldata" in line or "wobjdata" in line)
    res = compensate_program(m, _module(tcp, W, cf, wobj_decl=False, tool_decl=False), rapid, frame="measurement",
                             context="MODULE frames\n" + decl + "\nENDMODULE\n")
    assert not res.failed
    got = _controller_lands(m, res, W)
    assert np.linalg.norm(got[:, :3, 3] - tcp[:, :3, 3], axis=1).max() * 1e3 < 2e-3


def test_undeclared_tool_is_the_robot_files_tool_with_a_note(setup):
    m, q, D, W, tcp, cf = setup
    mod = _module(tcp, W, cf, tool_decl=False)
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert not res.failed
    assert res.targets[0].tool_delta is None
    assert "tool tGun is not declared" in res.notes[0] and "robot file's tool" in res.notes[0]
    # (the taught confdata were the real tool's: with the file's tool the joints may cross a quadrant, said)
    assert all("other quadrant data" in n for n in res.notes[1:]), res.notes


@pytest.mark.parametrize("wobj, why", [
    ('[TRUE,TRUE,"",{uf},{of}]', "held by the robot"),
    ('[FALSE,TRUE,"STN1",{uf},{of}]', "moved by a mechanical unit (STN1)"),
    ('[FALSE,TRUE,"",[[1,2,3],[2,0,0,0]],{of}]', "quaternion norm 2.0000"),
    ('[FALSE,TRUE,"",[1,2,3]]', "not [robhold, ufprog, ufmec, uframe, oframe]"),
    ('[FALSE,TRUE,"",[[1,2,3],[1,0,0 0]],{of}]', "could not be read"),
])
def test_unsupported_or_broken_work_objects_are_named(setup, wobj, why):
    m, q, D, W, tcp, cf = setup
    mod = _module(tcp, W, cf, wobj_decl=False).replace(
        "MODULE cell\n", "MODULE cell\n  PERS wobjdata wTable:=" + wobj.format(uf=_f(UF), of=_f(OF)) + ";\n")
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert len(res.failed) == 3 and all(why in r and "wobjdata wTable (line 2)" in r for _, r in res.failed), res.failed


def test_one_literal_used_in_two_work_objects_fails(setup):
    m, q, D, W, tcp, cf = setup
    mod = _module(tcp, W, cf).replace("  ENDPROC", "    MoveJ pA, v1000, z50, tGun;\n  ENDPROC")
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert len(res.failed) == 1 and "used with different tools or work objects" in res.failed[0][1]
    assert "wTable" in res.failed[0][1] and "wobj0" in res.failed[0][1]


def test_cli_refuses_unknown_work_object_and_takes_context(tmp_path, capsys):
    """Through the CLI on a real model file (UR10, few steps): unknown work object -> exit 2, one line per
    target naming it, nothing written; the module that declares it given with --context -> written."""
    import warnings

    from comp_models import tiny_model_file

    from hykin.hybrid.model import HybridModel

    model = tiny_model_file()
    m = HybridModel.load(model)
    q = m.nominal.random_joints(4, 8, margin=0.3)
    D = se3.invert(m.nominal.tool) @ TF
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tcp = real_tcp(m, m.predict(q), D)
    prog = tmp_path / "job.mod"
    prog.write_text(_module(tcp, UF @ OF, abb_confdata(m.nominal, q), wobj_decl=False))
    out = tmp_path / "job_comp.mod"
    code, _, err = run(["compensate", str(model), str(prog), "-o", str(out), "--frame", "measurement"], capsys)
    assert code != 0 and not out.exists()
    assert err.count("target's frame unknown (") == 3 and "3 of 4 targets with unknown frames; nothing written" in err
    ctx = tmp_path / "frames.sys"
    full = _module(tcp, UF @ OF, abb_confdata(m.nominal, q))
    ctx.write_text("MODULE frames(SYSMODULE)\n" + "\n".join(ln for ln in full.splitlines() if "wobjdata" in ln) + "\nENDMODULE\n")
    for bad in ("-1", "91", "nan"):
        code, _, err = run(["compensate", str(model), str(prog), "-o", str(out), "--frame", "measurement",
                            "--context", str(ctx), "--config-slack-deg", bad], capsys)
        assert code != 0 and not out.exists() and "--config-slack-deg must be within 0-90 deg" in err
    code, o, err = run(["compensate", str(model), str(prog), "-o", str(out), "--frame", "measurement",
                        "--context", str(ctx)], capsys)
    assert code == 0, err
    assert out.exists() and out.read_text() != prog.read_text()
    # two context files, the work object broken in the second: the message names that file and its line
    tools = tmp_path / "tools.sys"
    tools.write_text("MODULE tools(SYSMODULE)\n  ! tools of the cell\n\n  PERS tooldata tOther:=[TRUE," + _f(TF)
                     + ",[1,[0,0,1],[1,0,0,0],0,0,0]];\nENDMODULE\n")
    broken = tmp_path / "broken.sys"
    broken.write_text("MODULE frames(SYSMODULE)\n  ! the fixture\n  TASK PERS wobjdata wTable:=[FALSE,TRUE,\"\","
                      "[[1,2,3],[1,0,0 0]]," + _f(OF) + "];\nENDMODULE\n")
    out2 = tmp_path / "job2.mod"
    code, _, err = run(["compensate", str(model), str(prog), "-o", str(out2), "--frame", "measurement",
                        "--context", str(tools), "--context", str(broken)], capsys)
    assert code != 0 and not out2.exists()
    assert "wobjdata wTable (broken.sys, line 3) could not be read" in err, err


def _krl_frame(T) -> str:
    a, b, c = krl.abc_from_matrix(T[:3, :3])
    x, y, z = T[:3, 3] * 1e3
    return f"X {x:.6f},Y {y:.6f},Z {z:.6f},A {a:.8f},B {b:.8f},C {c:.8f}"


def test_krl_base_and_tool_from_inline_forms_and_config():
    """KRL inline forms (FDAT_ACT with BASE_NO / TOOL_NO), then $BASE/$TOOL = $NULLFRAME: the first two
    targets are in BASE_DATA[1] with TOOL_DATA[2] (from $config.dat given as context), the third in
    the robot base with the robot file's tool. A stand-in KUKA controller lands each on the truth."""
    m = exact("kuka-kr6-r900", 12)
    nom = m.nominal
    q = nom.random_joints(3, 9, margin=0.25)
    q[:, 4] = np.abs(q[:, 4]) + 0.3
    B1 = se3.make_transform(krl.matrix_from_abc(30.0, 0.0, 5.0), np.array([1.2, -0.3, 0.05]))
    TL = se3.make_transform(krl.matrix_from_abc(0.0, 15.0, 0.0), np.array([0.01, 0.0, 0.18]))
    D = se3.invert(nom.tool) @ TL
    Ws, Ds = [B1, B1, np.eye(4)], [D, D, np.eye(4)]
    tcp = np.stack([real_tcp(m, fk(m.robot_, q[k:k + 1])[0], Ds[k]) for k in range(3)])
    S, T = kuka_status(nom, q)
    dat = "DEFDAT cell\r\n" + "".join(
        f"DECL E6POS XP{k + 1}={{{_krl_frame(se3.invert(Ws[k]) @ tcp[k])},S {S[k]},T {T[k]},E1 0.0}}\r\n" for k in range(3))
    dat += 'DECL FDAT FP1={TOOL_NO 2,BASE_NO 1,IPO_FRAME #BASE,POINT2[] " "}\r\nENDDAT\r\n'
    fold = lambda k, mv: (f";FOLD {mv} P{k} Vel=2 m/s CPDAT1 Tool[2] Base[1];%{{PE}}\r\n$BWDSTART=FALSE\r\n"
                          f"FDAT_ACT=FP1\r\nBAS(#CP_PARAMS,2)\r\n{mv} XP{k}\r\n;ENDFOLD\r\n")
    src = ("DEF cell( )\r\n" + fold(1, "PTP") + fold(2, "LIN")
           + "$BASE=$NULLFRAME\r\n$TOOL=$NULLFRAME\r\nLIN XP3\r\nEND\r\n")
    config = (f"DEFDAT $CONFIG\r\nBASE_DATA[1]={{{_krl_frame(B1)}}}\r\n"
              f"TOOL_DATA[2]={{{_krl_frame(TL)}}}\r\nENDDAT\r\n")
    res = compensate_program(m, dat, krl, frame="measurement", context=src + config)
    assert len(res.targets) == 3 and not res.failed, res.failed
    assert np.abs(np.stack([t.pose for t in res.targets]) - tcp).max() < 1e-8
    new, _ = krl.find_targets(res.text, nom, context=src + config)
    local = np.stack([se3.invert(Ws[k]) @ new[k].pose for k in range(3)])
    qc = match_kuka_status(nom, np.stack([Ws[k] @ local[k] @ se3.invert(Ds[k]) for k in range(3)]),
                           [t.config["S"] for t in new], [t.config["T"] for t in new])
    got = np.stack([real_tcp(m, fk(m.robot_, qc[k:k + 1])[0], Ds[k]) for k in range(3)])
    assert np.linalg.norm(got[:, :3, 3] - tcp[:, :3, 3], axis=1).max() * 1e3 < 2e-3
    # without $config.dat: base 1 is unknown (those targets fail, saying so), tool 2 is noted
    r0 = compensate_program(m, dat, krl, frame="measurement", context=src)
    assert [line for line, _ in r0.failed] == [2, 3] and all("BASE_DATA[1]" in r and "$config.dat" in r for _, r in r0.failed)
    assert any("tool 2 (TOOL_DATA[2]) was not read" in n for n in r0.notes)
    assert r0.comp.success.tolist() == [False, False, True]


def test_rapid_statement_forms():
    """Which argument is the target and which the tool, across statement forms: \\Conc first, optional
    arguments after positional ones without a comma, RelTool(..), MoveC's two points, two statements on
    one line, SearchL's SearchPoint (written by the instruction: not a target), an instruction hykin
    does not know that names a work object (its tool agrees with any), one target in two work objects."""
    from hykin import load_robot

    rob = load_robot("abb-irb2400")
    R = "[[900,0,800],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]]"
    mod = f"""MODULE m
  LOCAL PERS tooldata tGun := [ TRUE, [ [0, 0, 150],
      [1, 0, 0, 0] ], [1.5,[0,0,50],[1,0,0,0],0,0,0] ];
  TASK PERS wobjdata wT:=[FALSE,TRUE,"",[[100,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];
  CONST robtarget p1:={R};
  CONST robtarget p2:={R};
  VAR robtarget p3:={R};
  CONST robtarget p4:={R};
  PROC main()
    MoveL \\Conc, p1, v100 \\V:=500, z10 \\Z:=5, tGun \\WObj:=wT \\Corr;
    MoveJ RelTool(p2, 0, 0, 10),v1000,fine,tGun\\WObj:=wT; MoveC p2, {R}, v100, z5, tGun\\WObj:=wT;
    IF reg1 = 1 THEN
      MoveL p3, v100, fine, tool0;
    ENDIF
    p3 := Offs(p1, 0, 0, 10);
    SearchL \\Stop, di1, p3, p1, v100, tGun\\WObj:=wT;
    MyMove p1, 5 \\WObj:=wT;
    MyMove p4, 5 \\WObj:=wT;
    MoveL p4, v100, z10, tool0;
  ENDPROC
ENDMODULE
"""
    t, notes = rapid.find_targets(mod, rob)
    assert [x.name for x in t] == ["p1", "p2", "p3", "p4", ""]
    assert notes == ["10: tooldata tGun (line 2) carries 1.5 kg, the robot file's payload is 0 kg: give --payload-kg 1.5 "
                     "if the robot carries that load while running these targets"]
    W = se3.make_transform(np.eye(3), np.array([0.1, 0.0, 0.0]))
    D = se3.invert(rob.tool) @ se3.make_transform(np.eye(3), np.array([0.0, 0.0, 0.15]))
    for k in (0, 1, 4):
        assert not t[k].error and np.allclose(t[k].frame, W) and np.allclose(t[k].tool_delta, D), k
    assert not t[2].error and t[2].frame is None and t[2].tool_delta is None  # MoveL p3 ... tool0 only
    assert "used with different tools or work objects" in t[3].error and "tool? \\WObj:=wT" in t[3].error


def test_cli_csv_targets_of_another_tcp(tmp_path, capsys):
    """``--tool``: CSV targets that are poses of another TCP (given in the flange frame, mm and deg here)
    come back as the joints where the model puts that TCP on them, and commands of that TCP; without
    it the same file would be solved for the model's own TCP (other joints). Position-only targets
    and programs are refused with the option, in one line."""
    import csv
    import warnings

    from comp_models import tiny_model_file

    from hykin.hybrid.model import HybridModel

    model = tiny_model_file()
    m = HybridModel.load(model)
    nom = m.nominal
    q = nom.random_joints(20, 31, margin=0.3)
    tcp = se3.xyzrpy_to_transform(np.array([[0.02, -0.01, 0.16]]), np.radians([[5.0, -10.0, 30.0]]))[0]
    D = se3.invert(nom.tool) @ tcp
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        T = real_tcp(m, m.predict(q), D)
    xyz, quat = se3.transform_to_pose(T)
    # mm and degrees: --angle-unit reads the tool's angles and the file's joint columns (branch hints)
    src2 = tmp_path / "targets.csv"
    with open(src2, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "z", "qw", "qx", "qy", "qz"] + [f"q{j + 1}" for j in range(nom.dof)])
        for k in range(len(q)):
            w.writerow([*(f"{v:.9f}" for v in xyz[k] * 1e3), *(f"{v:.12f}" for v in quat[k]),
                        *(f"{v:.12f}" for v in np.degrees(q[k]))])
    out = tmp_path / "cmd.csv"
    code, o, err = run(["compensate", str(model), str(src2), "-o", str(out), "--length-unit", "mm", "--angle-unit", "deg",
                        "--tool", "20,-10,160,5,-10,30"], capsys)
    assert code == 0, err
    got = {c: np.array([float(r[c]) for r in csv.DictReader(open(out))]) for c in ["x", "y", "z", "q1", "q2", "q3", "q4", "q5", "q6", "success"]}
    assert got["success"].all()
    qo = np.stack([got[f"q{j + 1}"] for j in range(6)], 1)
    assert np.abs(qo - q).max() < 1e-6
    want = se3.invert(nom.base) @ fk(nom, q) @ D  # the controller's pose of that TCP at those joints
    assert np.abs(np.stack([got["x"], got["y"], got["z"]], 1) - want[:, :3, 3]).max() < 1e-8
    # the same file read as the model's own TCP: other joints (160 mm of tool moves them)
    out2 = tmp_path / "cmd_own.csv"
    code, _, err = run(["compensate", str(model), str(src2), "-o", str(out2), "--length-unit", "mm", "--angle-unit", "deg"], capsys)
    assert code == 0, err
    q_own = np.stack([np.array([float(r[f"q{j + 1}"]) for r in csv.DictReader(open(out2))]) for j in range(6)], 1)
    assert np.nanmax(np.abs(q_own - q)) > 0.01
    # refusals: position-only targets, a program, mm read as m
    pos = tmp_path / "pos.csv"
    pos.write_text("x,y,z\n" + "\n".join(",".join(f"{v:.3f}" for v in p * 1e3) for p in xyz) + "\n")
    code, _, err = run(["compensate", str(model), str(pos), "-o", str(tmp_path / "a.csv"), "--length-unit", "mm",
                        "--tool", "20,-10,160"], capsys)
    assert code != 0 and "--tool needs the targets' orientations" in err and not (tmp_path / "a.csv").exists()
    code, _, err = run(["compensate", str(model), str(src2), "-o", str(tmp_path / "b.csv"), "--tool", "20,-10,160"], capsys)
    assert code != 0 and "--length-unit mm" in err and not (tmp_path / "b.csv").exists()
    prog = tmp_path / "job.script"
    prog.write_text("movel(p[0.5, 0.1, 0.4, 0, 3.14, 0], a=1, v=0.1)\n")
    code, _, err = run(["compensate", str(model), str(prog), "-o", str(tmp_path / "c.script"), "--tool", "0,0,0.1"], capsys)
    assert code != 0 and "--tool applies to CSV targets" in err


def test_urscript_moves_relative_to_a_feature_the_script_defines():
    """``movel(pose_trans(Plane_1, p[..]))`` and ``movel(pose_trans(Plane_1, W1))`` with ``global Plane_1 =
    p[..]``: the targets are in Plane_1's frame and written back in it (a stand-in UR controller
    evaluates pose_trans and lands the real robot on the wanted poses); a feature the script does not
    define (the installation's) keeps its line, noted; the feature's own literal is never rewritten."""
    from hykin.compensation import urscript
    from hykin.kinematics.ik import ik

    m = exact("ur10", 11)
    nom = m.nominal
    home = np.array([0.2, -1.5, 1.6, -1.6, -1.5, 0.3])
    q = home + np.random.default_rng(4).normal(0, 0.1, (3, 6))
    want = fk(m.robot_, q)
    F = se3.make_transform(se3.rotvec_to_matrix(np.array([0.1, -0.2, 0.7])), np.array([0.4, -0.3, 0.05]))
    loc = se3.invert(F) @ want

    def p(T):
        return "p[" + ", ".join(f"{v:.9f}" for v in (*T[:3, 3], *se3.matrix_to_rotvec(T[:3, :3]))) + "]"

    prog = (
        "def job():\n"
        f"  movej([{', '.join(f'{v:.5f}' for v in home)}], a=1.4, v=1.05)\n"
        f"  global Plane_1 = {p(F)}\n"
        f"  global W1 = {p(loc[1])}\n"
        f"  movel(pose_trans(Plane_1, {p(loc[0])}), a=1.2, v=0.25)\n"
        "  movel(pose_trans(Plane_1, W1), a=1.2, v=0.25)\n"
        f"  movel(pose_trans(Plane_2, {p(loc[2])}), a=1.2, v=0.25)\n"
        "end\n"
    )
    res = compensate_program(m, prog, urscript, frame="measurement")
    assert [t.line for t in res.targets] == [4, 5] and not res.failed
    assert any("feature Plane_2, which this script does not define" in n for n in res.notes)
    assert _diff(prog, res.text) == {4, 5}  # W1's and the inline literal; Plane_1 and Plane_2's line kept
    # the feature's pose where the move is counts: W1 may be assigned before Plane_1 is
    swapped = prog.replace(f"  global Plane_1 = {p(F)}\n  global W1 = {p(loc[1])}\n",
                           f"  global W1 = {p(loc[1])}\n  global Plane_1 = {p(F)}\n")
    assert swapped != prog
    r2 = compensate_program(m, swapped, urscript, frame="measurement")
    assert [t.line for t in r2.targets] == [3, 5] and np.abs(r2.targets[0].pose - want[1]).max() < 1e-8
    order = [1, 0]  # in the text W1's literal (line 4) comes before the inline one (line 5)
    assert np.abs(np.stack([t.pose for t in res.targets]) - want[order]).max() < 1e-8
    new, _ = urscript.find_targets(res.text, nom)
    cur = home
    for k, t in zip(order, new):  # stand-in controller: pose_trans(Plane_1, literal), IK nearest
        r = ik(nom, t.pose[None], all_branches=True).nearest_to(cur, nom.lower, nom.upper)
        cur = r.q[0]
        assert np.linalg.norm(fk(m.robot_, cur[None])[0, :3, 3] - want[k, :3, 3]) * 1e3 < 2e-3


def _diff(a: str, b: str) -> set:
    la, lb = a.split("\n"), b.split("\n")
    return {i for i, (x, y) in enumerate(zip(la, lb), 1) if x != y}


def test_rapid_targets_in_one_line_ifs_routine_parameters_and_assignments(setup):
    """Moves hykin must follow to know a target's frames: a compact IF (``IF c MoveL p, ..;``), an IF
    with its THEN on one line, a robtarget passed to a routine of the module (the routine's moves on
    that parameter), a literal assigned to a VAR robtarget inside a routine. Each lands through the
    stand-in controller in wTable with tGun; a robtarget passed only to a routine the module does not
    define fails, saying so; one only written to the teach pendant keeps the default frames."""
    m, q, D, W, tcp, cf = setup
    loc = se3.invert(W) @ tcp
    mod = (
        "MODULE cell\n"
        "  PERS tooldata tGun:=[TRUE," + _f(TF) + ",[2.5,[0,0,80],[1,0,0,0],0,0,0]];\n"
        "  TASK PERS wobjdata wTable:=[FALSE,TRUE,\"\"," + _f(UF) + "," + _f(OF) + "];\n"
        f"  CONST robtarget pA:={_robt(loc[0], cf[0])};\n"
        f"  CONST robtarget pB:={_robt(loc[1], cf[1])};\n"
        f"  CONST robtarget pC:={_robt(loc[2], cf[2])};\n"
        "  CONST robtarget pX:=[[500,0,600],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
        f"  CONST robtarget pY:={_robt(fk(m.robot_, q[:1])[0], cf[0])};\n"
        "  VAR robtarget pT;\n"
        "  PERS bool bPart:=TRUE;\n"
        "  PROC main()\n"
        "    IF bPart MoveL pA, v100, fine, tGun\\WObj:=wTable;\n"
        "    IF bPart THEN MoveJ pB, v1000, z50, tGun\\WObj:=wTable; ENDIF\n"
        "    PickAt 10, pC;\n"
        f"    pT := {_robt(loc[3], cf[3])};\n"
        "    MoveJ pT, v1000, z50, tGun\\WObj:=wTable;\n"
        "    ExtPick pX;\n"
        "    TPWrite \"at\" \\Pos:=pY;\n"
        "  ENDPROC\n"
        "  PROC PickAt(num n, robtarget pt, \\switch Slow)\n"
        "    MoveL Offs(pt, 0, 0, 50), v500, z10, tGun\\WObj:=wTable;\n"
        "    MoveL pt, v100, fine, tGun\\WObj:=wTable;\n"
        "  ENDPROC\n"
        "ENDMODULE\n"
    )
    res = compensate_program(m, mod, rapid, frame="measurement")
    names = [t.name for t in res.targets]
    # pT's literal is inline in its assignment; pY, which no motion moves to (TPWrite moves nothing), keeps
    # its literal: the module moves with other frames than wobj0/tool0, so pY's are not known
    assert names == ["pA", "pB", "pC", "pX", ""]
    assert any("pY (line 8)" in n and "kept" in n for n in res.notes), res.notes
    for k in (0, 1, 2, 4):
        t = res.targets[k]
        assert not t.error and np.allclose(t.frame, W) and np.allclose(t.tool_delta, D), (k, t.error)
    assert [line for line, _ in res.failed] == [7], res.failed
    assert "used only as an argument of ExtPick (line 17), a routine neither this module nor a --context" in res.failed[0][1]
    # ExtPick defined in a context module: pX takes the frames of its moves there
    lib = ("MODULE lib(SYSMODULE)\n  PROC ExtPick(robtarget p)\n    MoveL RelTool(p, 0, 0, -30), v200, z5, tGun"
           "\\WObj:=wTable;\n    MoveL p, v50, fine, tGun\\WObj:=wTable;\n  ENDPROC\nENDMODULE\n")
    rc = compensate_program(m, mod, rapid, frame="measurement", context=lib)
    assert rc.targets[3].frame is not None and np.allclose(rc.targets[3].frame, W) and not rc.targets[3].error
    # the stand-in controller: the rewritten literals in wTable with tGun, on their confdata
    new, _ = rapid.find_targets(res.text, m.nominal, context="")
    nom = m.nominal
    rows = [0, 1, 2, 4]
    flange = np.stack([new[k].pose @ se3.invert(D) for k in rows])  # W · literal: the wanted flange pose
    qc = match_abb_confdata(nom, flange, np.array([new[k].config["conf"] for k in rows]))
    got = real_tcp(m, fk(m.robot_, qc), D)
    assert np.linalg.norm(got[:, :3, 3] - tcp[:, :3, 3], axis=1).max() * 1e3 < 2e-3
