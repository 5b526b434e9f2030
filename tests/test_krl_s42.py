"""Stop 42, probe AX: a KRL target reached right after a move to a point this run does not solve, and a
``.dat`` point moved to again."""

from __future__ import annotations

import numpy as np
from comp_models import exact
from test_krl_use import _axes, _q, _status, _xyzabc

from hykin import fk
from hykin.compensation import krl
from hykin.compensation.programs import compensate_program


def _case(seed: int):
    m = exact("kuka-kr6-r900", seed)
    nom = m.nominal
    q1 = _q(nom, [-15, -85, 95, 25, -40, 55])
    q2 = _q(nom, [10, -80, 95, 20, 40, -30])
    q3 = _q(nom, [-14, -86, 96, 27, -42, 57])
    tcp = fk(m.robot_, np.stack([q1, q2, q3]))
    config = f"DEFDAT $CONFIG\nDECL E6AXIS XHOME={{{_axes(nom, _q(nom, [0, -90, 90, 0, 0, 0]))},E1 0.0}}\nENDDAT\n"
    return m, nom, (q1, q2, q3), tcp, config


def test_a_lin_after_a_point_of_another_file_is_noted():
    """The .src alone (its .dat as context): ``LIN {..}`` right after ``PTP XP1``, a .dat point this run does
    not solve. Its arm configuration is unknown here (the walk took XHOME's and landed 1.76 mm off on the
    probe's robot): said, naming the motion."""
    m, nom, (q1, _, q3), tcp, config = _case(4)
    dat = f"DEFDAT job\nDECL E6POS XP1={{{_xyzabc(tcp[0])},{_status(nom, q1)},E1 0.0}}\nENDDAT\n"
    src = f"DEF job( )\n  PTP XHOME\n  PTP XP1\n  LIN {{{_xyzabc(tcp[2])}}} C_DIS\nEND\n"
    res = compensate_program(m, src, krl, frame="measurement", context=dat + config)
    assert any("line 4: comes after PTP XP1 (line 3 of the .src), a point not solved here" in n for n in res.notes), \
        res.notes
    # a LIN after an inline target of the same file: nothing said
    src2 = (f"DEF job( )\n  PTP XHOME\n  PTP {{{_xyzabc(tcp[0])},{_status(nom, q1)}}}\n"
            f"  LIN {{{_xyzabc(tcp[2])}}} C_DIS\nEND\n")
    res2 = compensate_program(m, src2, krl, frame="measurement", context=config)
    assert not any("a point not solved here" in n for n in res2.notes), res2.notes


def test_a_dat_point_moved_to_again_is_where_the_robot_comes_from():
    """``PTP XP1``, ``PTP XP2``, ``PTP XP1`` again, then ``LIN P3``: P3 is walked from XP1 (the motion just
    before it), not from XP2 (the target before it in first-use order)."""
    m, nom, (q1, q2, q3), tcp, config = _case(5)
    dat = (f"DEFDAT job\nDECL E6POS XP1={{{_xyzabc(tcp[0])},{_status(nom, q1)},E1 0.0}}\n"
           f"DECL E6POS XP2={{{_xyzabc(tcp[1])},{_status(nom, q2)},E1 0.0}}\n"
           f"DECL POS P3={{{_xyzabc(tcp[2])}}}\nENDDAT\n")
    src = "DEF job( )\n  PTP XHOME\n  PTP XP1\n  PTP XP2\n  PTP XP1\n  LIN P3\nEND\n"
    res = compensate_program(m, dat, krl, frame="measurement", context=src + config)
    names = [t.name for t in res.targets]
    p3 = res.targets[names.index("P3")]
    assert p3.after == names.index("XP1") and p3.reset is None
    assert not res.failed
    k = names.index("P3")
    assert np.abs(res.comp.q[k] - q3).max() < np.radians(5)  # XP1's branch, where the truth is
