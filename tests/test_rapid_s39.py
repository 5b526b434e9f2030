"""RAPID: run-time changes of tool/work object data and program displacement are refused naming the
statement; an undeclared tool is named in a failure it may explain (probe report s39)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_krl_s39 import model, status, taught  # noqa: F401  (model: the KRL tests' fixture)

from hykin.compensation import rapid
from hykin.compensation.programs import compensate_program




def robtarget(T, conf) -> str:
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    p = T[:3, 3] * 1e3
    return (f"[[{p[0]:.3f},{p[1]:.3f},{p[2]:.3f}],[{w:.8f},{x:.8f},{y:.8f},{z:.8f}],[{','.join(map(str, conf))}],"
            "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]")


def _conf(q) -> list:
    """ABB confdata of q (deg quadrants of axes 1, 4, 6; cfx from the KUKA status: overhead, elbow, A5)."""
    S, _ = status(q)
    quad = [int(np.floor(np.degrees(q[i]) / 90 + 1e-12)) for i in (0, 3, 5)]
    # this arm's wrist centre is on the A3 < φ side at zero (elbow < 0): forward = elbow < 0
    return quad + [4 * (S & 1) + 2 * ((S >> 1) & 1) + int(q[4] < 0)]


def _module(statement: str, tool: str = "tGun", wobj: str = "wTable") -> str:
    q1, T1 = taught([10, 20, 10, 5, 40, 5])
    q2, T2 = taught([14, 24, 6, 8, 42, 4])
    return ("MODULE M\n"
            "  PERS tooldata tGun:=[TRUE,[[0,0,0],[1,0,0,0]],[0,[0,0,1],[1,0,0,0],0,0,0]];\n"
            "  PERS wobjdata wTable:=[FALSE,TRUE,\"\",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];\n"
            f"  CONST robtarget p1:={robtarget(T1, _conf(q1))};\n"
            f"  CONST robtarget p2:={robtarget(T2, _conf(q2))};\n"
            "  VAR num z;\n"
            "  PROC main()\n"
            f"    MoveJ p1, v1000, z50, {tool}\\WObj:={wobj};\n"
            f"    {statement}\n"
            f"    MoveL p2, v1000, fine, {tool}\\WObj:={wobj};\n"
            "  ENDPROC\nENDMODULE\n")


@pytest.mark.parametrize("statement, refused", [
    ("tGun.tframe.trans.z:=250;", True),
    ("wTable.uframe.trans.z:=200;", True),
    ("wTable:=[FALSE,TRUE,\"\",[[0,0,50],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];", True),
    ("PDispOn \\ExeP:=p1, p1, tGun\\WObj:=wTable;", True),
    ("PDispOn \\ExeP:=p1, p1, tGun\\WObj:=wTable; PDispOff;", False),
    ("z:=wTable.uframe.trans.z + tGun.tframe.trans.z;", False),
])
def test_run_time_frame_changes_are_refused_naming_the_line(model, statement, refused):
    mod = _module(statement)
    res = compensate_program(model, mod, rapid, frame="measurement")
    if refused:
        assert [line for line, _ in res.failed] == [5]  # p2, moved to after the change
        assert "line 9" in res.failed[0][1] and "run time" in res.failed[0][1]
        assert res.n_compensated == 1
    else:
        assert not res.failed and res.n_compensated == 2


def test_undeclared_tool_is_named_in_the_failure(model):
    """p2 lies 5 m away: it fails; the undeclared tool tGripper, taken to be the robot file's tool, is
    named in the error as a possible cause (the reason alone would blame reach or confdata)."""
    lines = _module("z:=1;", tool="tGripper").split("\n")
    lines[4] = lines[4].replace(":=[[", ":=[[5000")
    res = compensate_program(model, "\n".join(lines), rapid, frame="measurement")
    assert [line for line, _ in res.failed] == [5]
    assert "tool tGripper is not declared" in res.failed[0][1]
    assert any("tool tGripper is not declared" in n for n in res.notes)


def test_unused_robtarget_keeps_its_literal_where_the_module_moves_with_other_frames(model):
    """A robtarget no motion moves to, in a module moving with tGun\\WObj:=wTable: its frames are not
    known, so it is kept and noted (before: compensated in wobj0 with tool0); in a module moving with
    tool0/wobj0 only it is compensated as those motions are."""
    q3, T3 = taught([12, 22, 8, 6, 41, 6])
    extra = f"  CONST robtarget p99:={robtarget(T3, _conf(q3))};\n"
    lines = _module("z:=1;").split("\n")
    mod = "\n".join(lines[:5] + [extra.rstrip("\n")] + lines[5:])
    res = compensate_program(model, mod, rapid, frame="measurement")
    assert not res.failed and res.n_compensated == 2
    assert extra.strip() in res.text  # p99's literal as written
    assert any("p99 (line 6)" in n and "kept" in n for n in res.notes), res.notes
    plain = "\n".join(lines[:5] + [extra.rstrip("\n")] + lines[5:]).replace("tGun\\WObj:=wTable", "tool0\\WObj:=wobj0")
    res2 = compensate_program(model, plain, rapid, frame="measurement")
    assert not res2.failed and res2.n_compensated == 3
    assert extra.strip() not in res2.text


def test_quadrant_changes_of_the_compensated_joints_are_noted():
    """Probe s41 AN: 4 rewritten cf1/cf4/cf6 quadrants without a word, one a cf1 1 -> -2 (axis 1 179.6° ->
    -179.9°: a joint move from a neighbour turns it by 359.5°). The note names each axis and its angle."""
    from types import SimpleNamespace

    from hykin import load_robot
    from hykin.compensation.program_checks import _abb_quadrants

    model = SimpleNamespace(nominal=load_robot("abb-irb2400"))
    q = np.radians([-179.9, 10.0, 20.0, 98.17, 30.0, 5.0])
    t = SimpleNamespace(line=36, config={"conf": [1, 0, 0, 0]})
    (got,) = _abb_quadrants(model, t, q, None)
    assert got.startswith("36 (cf1 1 -> -2: axis 1 -179.90°; cf4 0 -> 1: axis 4 +98.17°") and "cf6" not in got, got
    assert _abb_quadrants(model, SimpleNamespace(line=1, config={"conf": [-2, 1, 0, 0]}), q, None) == []


def test_taught_turns_of_axes_4_and_6_are_kept():
    """Probe s41 AO: axis 4 taught at +199.994° (±200°, cf4 2) was written at -160.006° (cf4 -2), axis 6 at
    399.994° (±400°, cf6 4) at 39.994° (cf6 0): the same pose, a full turn to unwind on the next move, and a
    note blaming a quadrant boundary. Whole turns from the taught quadrant go back to the taught turn."""
    from types import SimpleNamespace

    from comp_models import exact

    from hykin.compensation.branches import abb_confdata
    from hykin.compensation.program_checks import _taught_turns

    m = exact("abb-irb2400", 3)
    taught = np.radians([[10.0, 20.0, 10.0, 199.994, 30.0, 20.0], [-30.0, 10.0, 5.0, 40.0, 50.0, 399.994]])
    conf = abb_confdata(m.nominal, taught)
    q_written = taught.copy()
    q_written[0, 3] -= 2 * np.pi  # what the old code wrote: another turn of the same pose
    q_written[1, 5] -= 2 * np.pi
    comp = SimpleNamespace(q=q_written.copy())
    targets = [SimpleNamespace(config={"conf": list(c)}) for c in conf]
    _taught_turns(m, targets, comp, np.arange(2), None)
    np.testing.assert_allclose(comp.q, taught, atol=1e-12)
    assert (abb_confdata(m.nominal, comp.q) == conf).all()
