"""KRL compensation: circular angle, KUKA S/T turn boundaries, the walk after an S/T point, run-time frame
changes, points the .src never moves to (probe report s39).

The robot is a Fanuc-M-20-like 6R arm in standard DH (A6 over ±360°); the truth is a deviated copy
(``comp_models.deviate``: the model predicts it exactly). The literals are what the controller records:
the NOMINAL pose of taught joints. After compensation a stand-in KUKA controller written here (its own
DH forward kinematics, its own S/T rule: S bit 0 wrist centre behind axis 1, bit 1 elbow angle >= 0, bit 2
A5 <= 0; T bit i = A(i+1) < 0) executes the written literals on the nominal arm: a point with S/T takes
the nominal solution with exactly those, one without the solution nearest the joints the robot is at.
The truth robot at those joints must reach the taught pose.
"""

from __future__ import annotations

import itertools
import re

import numpy as np
import pytest
from comp_models import ExactModel, deviate, real_tcp

from hykin import fk
from hykin.compensation import krl
from hykin.compensation.programs import compensate_program
from hykin.io.robot_file import load_robot
from hykin.kinematics.ik import ik

D = np.pi / 180
A_ = np.array([0.150, 0.790, 0.150, 0, 0, 0])
ALPHA = np.array([-90, 0, -90, 90, -90, 0]) * D
D_ = np.array([0.525, 0, 0, 0.860, 0, 0.100])
THETA = np.array([0, -90, 0, 0, 0, 0]) * D
LO = np.array([-170, -100, -170, -200, -135, -360]) * D
HI = np.array([170, 160, 190, 200, 135, 360]) * D

_TOML = """name = "fanuc-like-m20"
convention = "dh"
length_unit = "mm"
angle_unit = "deg"
""" + "".join(
    f"\n[[joints]]\na = {a * 1e3:g}\nalpha = {al / D:g}\nd = {d * 1e3:g}\ntheta = {th / D:g}\nmin = {lo / D:g}\nmax = {hi / D:g}\n"
    for a, al, d, th, lo, hi in zip(A_, ALPHA, D_, THETA, LO, HI))


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    p = tmp_path_factory.mktemp("rob") / "robot.toml"
    p.write_text(_TOML)
    nom = load_robot(p)
    return ExactModel(nom, deviate(nom, 11, sigma_m=6e-4, sigma_rad=np.radians(0.08)))


# ---- the stand-in controller (independent of hykin.compensation) -------------------------------

def _dh(a, al, d, th):
    ca, sa, ct, st = np.cos(al), np.sin(al), np.cos(th), np.sin(th)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])


def _frames(q):
    T, out = np.eye(4), []
    for i in range(6):
        out.append(T.copy())
        T = T @ _dh(A_[i], ALPHA[i], D_[i], q[i] + THETA[i])
    out.append(T)
    return out


def nominal_fk(q) -> np.ndarray:
    return _frames(q)[-1]


def status(q) -> tuple[int, int]:
    """KUKA (S, T) of joints q (rad) on the nominal arm."""
    fr = _frames(q)
    o = [f[:3, 3] for f in fr]
    pw = o[4]  # axes 4 and 5 intersect at frame 4's origin (spherical wrist)
    x1 = fr[1][:3, 0] - fr[1][:3, 0] @ np.array([0, 0, 1.0]) * np.array([0, 0, 1.0])
    overhead = (pw - o[0]) @ x1 < 0
    lower, upper = o[2] - o[1], pw - o[2]
    elbow = np.arctan2(np.cross(lower, upper) @ fr[2][:3, 2], lower @ upper)
    S = int(overhead) + 2 * int(elbow >= 0) + 4 * int(q[4] <= 0)
    return S, sum(1 << i for i in range(6) if q[i] < 0)


def solutions(T) -> list:
    """Every nominal solution of T within the limits, each 2π representation of it."""
    br = ik(_ROB[0], T[None], all_branches=True)
    out = []
    for q, ok in zip(br.q[0], br.success[0]):
        if not ok or not np.isfinite(q).all():
            continue
        q = (q + np.pi) % (2 * np.pi) - np.pi
        assert np.allclose(nominal_fk(q), T, atol=1e-8)  # checked with our own FK
        for c in itertools.product(*[[v + k * 2 * np.pi for k in (-1, 0, 1) if LO[j] - 1e-9 <= v + k * 2 * np.pi <= HI[j] + 1e-9]
                                     for j, v in enumerate(q)]):
            if not any(np.allclose(c, x, atol=1e-7) for x in out):
                out.append(np.array(c))
    return out


_ROB = []  # the nominal robot, for hykin's closed-form IK (its solutions are checked with our FK)


def controller(nom, steps) -> list:
    """Joints per step: ("joint", q) moves there; ("pose", T, {"S", "T"} or {}) the solution with that S/T
    (the one nearest zero where several), else the one nearest the current joints."""
    _ROB[:] = [nom]
    cur, out = np.zeros(6), []
    for kind, value, *cfg in steps:
        if kind == "joint":
            cur = np.asarray(value, float)
            continue
        sols = solutions(value)
        if cfg and cfg[0]:
            sols = [s for s in sols if status(s) == (cfg[0]["S"], cfg[0]["T"])]
            assert sols, f"no nominal solution with S {cfg[0]['S']}, T {cfg[0]['T']}"
            cur = min(sols, key=lambda s: np.linalg.norm(s))
        else:
            cur = min(sols, key=lambda s: np.linalg.norm(s - cur))
        out.append(cur)
    return out


# ---- literals --------------------------------------------------------------------------------

def _abc(R) -> tuple:
    b = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    a = np.arctan2(R[1, 0], R[0, 0])
    c = np.arctan2(R[2, 1], R[2, 2])
    return np.degrees([a, b, c])


def agg(T) -> str:
    x, y, z = T[:3, 3] * 1e3
    a, b, c = _abc(T[:3, :3])
    return f"X {x:.4f},Y {y:.4f},Z {z:.4f},A {a:.5f},B {b:.5f},C {c:.5f}"


def read(text: str, line: int, k: int = 0) -> tuple:
    """(pose, {"S", "T"} or {}) of the k-th Cartesian aggregate on ``line`` (1-based), read here."""
    body = [b for b in re.findall(r"\{([^{}]*)\}", text.split("\n")[line - 1]) if re.search(r"\bX\s", b)][k]
    v = {n: float(t) for n, t in re.findall(r"\b([XYZABCST])\s+([-+\d.eE]+)", body)}
    a, b, c = np.radians([v["A"], v["B"], v["C"]])
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rz @ Ry @ Rx, np.array([v["X"], v["Y"], v["Z"]]) * 1e-3
    return T, ({"S": int(v["S"]), "T": int(v["T"])} if "S" in v else {})


def landed_mm(m, q, want) -> float:
    return float(np.linalg.norm(fk(m.robot_, np.asarray(q)[None])[0][:3, 3] - want[:3, 3]) * 1e3)


def taught(deg, rounding: float = 0.0) -> tuple:
    """(joints, nominal pose) of axis angles ``deg``; ``rounding`` (rad) added to A6 in the pose only: a
    point recorded at A6 = 0.000° whose literal's rounding solves to A6 = -2e-6 rad."""
    q = np.radians(np.asarray(deg, float))
    return q, nominal_fk(q + np.r_[0, 0, 0, 0, 0, rounding])


def _changed(a: str, b: str) -> set:
    return {i for i, (x, y) in enumerate(zip(a.split("\n"), b.split("\n")), 1) if x != y}


# ---- 1: CIRC aux, end CA angle ---------------------------------------------------------------

@pytest.mark.parametrize("ca", [" CA 90.0", ", CA -45.5"])
def test_circ_with_circular_angle_compensates_both_points(model, ca):
    """``CIRC {aux}, {end} CA 90.0`` (with or without a comma): the end point is a target as without CA;
    the controller (walking from the PTP joints) lands on both; the CA clause is kept verbatim."""
    q0 = np.radians([10, 20, 10, 5, 40, 5])
    qa, Ta = taught([14, 24, 6, 8, 42, 4])
    qe, Te = taught([18, 28, 2, 11, 44, 3])
    src = ("DEF c( )\n"
           f"PTP {{A1 10,A2 20,A3 10,A4 5,A5 40,A6 5}}\n"
           f"CIRC {{{agg(Ta)}}}, {{{agg(Te)}}}{ca} C_DIS\n"
           "END\n")
    res = compensate_program(model, src, krl, frame="measurement")
    assert not res.failed and len(res.targets) == 2 and res.n_compensated == 2
    assert not any("outside a motion" in n for n in res.notes)
    line = res.text.split("\n")[2]
    assert line.endswith(f"}}{ca} C_DIS")
    (pa, _), (pe, _) = read(res.text, 3, 0), read(res.text, 3, 1)
    qs = controller(model.nominal, [("joint", q0), ("pose", pa, {}), ("pose", pe, {})])
    # the truth must reach the wanted (taught) poses: the truth at the taught joints is off by mm
    wa, we = fk(model.robot_, qa[None])[0], fk(model.robot_, qe[None])[0]
    assert landed_mm(model, qa, Ta) > 0.5 and landed_mm(model, qe, Te) > 0.5
    assert landed_mm(model, qs[0], Ta) < 2e-3 and landed_mm(model, qs[1], Te) < 2e-3, (wa, we)


# ---- 4 / 3: a joint taught at 0° and the taught S/T ------------------------------------------------

def test_a6_taught_at_zero_stays_near_zero_and_t_follows(model):
    """A point taught at A6 = 0° with T 0, whose compensated A6 is a hair below 0 (this truth): the
    controller must turn A6 by -0.25°, not by +359.75°; T is rewritten with bit 5 set, S kept."""
    q, T = taught([150, 30, 0, 10, 40, 0], -2e-6)
    S, Tt = status(q)
    assert (S, Tt) == (2, 0)
    dat = f"DEFDAT a\nDECL E6POS XP4={{{agg(T)},S {S},T {Tt},E1 0.0}}\nENDDAT\n"
    res = compensate_program(model, dat, krl, frame="measurement")
    assert not res.failed
    pose, cfg = read(res.text, 2)
    assert cfg["S"] == S and cfg["T"] & 32  # A6 < 0 now
    (qc,) = controller(model.nominal, [("pose", pose, cfg)])
    assert np.abs(np.degrees(qc - q)).max() < 1.0  # no full turn of A6
    assert landed_mm(model, qc, T) < 2e-3
    assert any("T 0 -> " in n for n in res.notes)


@pytest.mark.parametrize("seed", [11, 4])
def test_taught_status_is_kept_where_the_real_robot_has_it(model, seed):
    """``S 1, T 0`` taught at (20, 60, 120, 10, 30, 0)°: the real robot reaches the pose on the same S/T
    (A6 = +0.13°, +12.5° for these truths); the written S/T must stay 1/0 (no wrist flip: a hint at
    A6 = 360° put the real solution beyond the limit) and the controller lands on it."""
    model = ExactModel(model.nominal, deviate(model.nominal, seed, sigma_m=6e-4, sigma_rad=np.radians(0.08)))
    q, T = taught([20, 60, 120, 10, 30, 0], -2e-6)
    S, Tt = status(q)
    assert (S, Tt) == (1, 0)
    dat = f"DEFDAT a\nDECL E6POS XP7={{{agg(T)},S {S},T {Tt},E1 0.0}}\nENDDAT\n"
    res = compensate_program(model, dat, krl, frame="measurement")
    assert not res.failed
    pose, cfg = read(res.text, 2)
    assert cfg["S"] == 1 and (cfg["T"] == 0 or seed == 4)  # seed 4: A4 crosses 0 (10° -> -0.8°): T 8, noted
    (qc,) = controller(model.nominal, [("pose", pose, cfg)])
    assert np.abs(np.degrees(qc - q)).max() < 15.0  # a wrist flip turns A4 and A6 by ~180°
    assert landed_mm(model, qc, T) < 2e-3
    assert not any("another configuration" in n for n in res.notes)
    assert (cfg["T"] == 0) != any("T 0 -> 8" in n for n in res.notes)


def test_lost_status_is_noted(model):
    """A1 taught at 169.95°: this truth needs A1 > 170° on the taught S, so the real robot reaches the
    pose only in another configuration: that is said in a note naming the line and the S change."""
    q, T = taught([169.95, 30, 0, 10, 40, 0])
    S, Tt = status(q)
    dat = f"DEFDAT a\nDECL E6POS XP4={{{agg(T)},S {S},T {Tt},E1 0.0}}\nENDDAT\n"
    res = compensate_program(model, dat, krl, frame="measurement")
    pose, cfg = read(res.text, 2)
    if res.failed or cfg["S"] == S:
        pytest.skip("this truth reaches the taught S")
    assert any(f"2 (S {S} -> {cfg['S']})" in n for n in res.notes)
    (qc,) = controller(model.nominal, [("pose", pose, cfg)])
    assert landed_mm(model, qc, T) < 2e-3


# ---- 2: the walk after an S/T point at A6 = 0 -------------------------------------------------

def test_walk_after_status_point_continues_from_its_joints(model):
    """``PTP XP9`` (S 2, T 0, A6 = 0) then ``PTP XP8`` without S/T: XP8's branch is the solution nearest
    XP9's joints (as the controller takes it), not the wrist-flipped one a hint at A6 = 360° is nearer."""
    q9, T9 = taught([30, 30, 10, 0, 100, 0], -2e-6)
    q8, T8 = taught([5, 130, -60, 0, 60, 0])
    S, Tt = status(q9)
    dat = (f"DEFDAT w\nDECL E6POS XP9={{{agg(T9)},S {S},T {Tt},E1 0.0}}\n"
           f"DECL E6POS XP8={{{agg(T8)},E1 0.0}}\nENDDAT\n")
    src = "DEF w( )\nPTP XP9\nPTP XP8\nEND\n"
    res = compensate_program(model, dat, krl, frame="measurement", context=src)
    assert not res.failed and res.n_compensated == 2
    p9, c9 = read(res.text, 2)
    p8, c8 = read(res.text, 3)
    qs = controller(model.nominal, [("pose", p9, c9), ("pose", p8, c8)])
    assert np.abs(np.degrees(qs[1] - q8)).max() < 1.0  # the taught branch, not the flipped wrist
    assert landed_mm(model, qs[0], T9) < 2e-3 and landed_mm(model, qs[1], T8) < 2e-3


# ---- 6: run-time changes of frame data ---------------------------------------------------------

_CONFIG = ("DEFDAT $CONFIG\nDECL FRAME BASE_DATA[32]\nBASE_DATA[1]={X 900.0,Y -200.0,Z 150.0,A 25.0,B 0.5,C -0.3}\n"
           "DECL FRAME TOOL_DATA[16]\nTOOL_DATA[2]={X 12.5,Y -4.0,Z 215.0,A 0.0,B 40.0,C 0.0}\nENDDAT\n")


@pytest.mark.parametrize("change, refused", [
    ("$TOOL.X = 30.0", True),
    ("$BASE.Z = $BASE.Z + 100.0", True),
    ("BASE_DATA[1].Z = BASE_DATA[1].Z + 20.0\n$BASE = BASE_DATA[1]", True),
    ("TOOL_DATA[2] = {X 0,Y 0,Z 100,A 0,B 0,C 0}\n$TOOL = TOOL_DATA[2]", True),
    ("IF $BASE.Z == 100.0 THEN\n  $VEL.CP = 0.1\nENDIF\nfRead = $TOOL", False),
])
def test_run_time_frame_changes_are_refused_naming_the_line(model, change, refused):
    """A change of $TOOL/$BASE components or of BASE_DATA/TOOL_DATA entries before a motion makes the
    targets moved to after it fail, naming the statement and its line; reading frames does not."""
    q1, T1 = taught([10, 20, 10, 5, 40, 5])
    q2, T2 = taught([14, 24, 6, 8, 42, 4])
    src = ("DEF k( )\nDECL FRAME fRead\n$BASE = $NULLFRAME\n$TOOL = $NULLFRAME\n"
           f"LIN {{{agg(T1)}}}\n{change}\nLIN {{{agg(T2)}}}\nEND\n")
    res = compensate_program(model, src, krl, frame="measurement", context=_CONFIG)
    n_change = change.count("\n") + 1
    if refused:
        assert [line for line, _ in res.failed] == [7 + n_change - 1]
        assert "line 6" in res.failed[0][1] and "run time" in res.failed[0][1]
        assert res.n_compensated == 1
    else:
        assert not res.failed and res.n_compensated == 2


# ---- 5: a .dat point the .src never moves to ----------------------------------------------------

def test_point_not_moved_to_is_kept_with_a_note(model):
    """The .src selects base 1 / tool 2 and moves to XP8 only: XP9's frame where it is used is unknown,
    so its literal stays byte for byte and a note names it; XP8 is compensated in base 1 / tool 2."""
    B1 = read("{X 900.0,Y -200.0,Z 150.0,A 25.0,B 0.5,C -0.3}", 1)[0]
    TL2 = read("{X 12.5,Y -4.0,Z 215.0,A 0.0,B 40.0,C 0.0}", 1)[0]
    q8, F8 = taught([5, 100, -40, 0, 60, 0])
    _, F9 = taught([30, 30, 10, 0, 100, 0])
    T8, T9 = (np.linalg.inv(B1) @ F @ TL2 for F in (F8, F9))  # literals: the tool's pose in base 1
    dat = (f"DEFDAT w\nDECL E6POS XP9={{{agg(T9)},S 2,T 0,E1 0.0}}\n"
           f"DECL E6POS XP8={{{agg(T8)},E1 0.0}}\nENDDAT\n")
    src = "DEF w( )\n$BASE = BASE_DATA[1]\n$TOOL = TOOL_DATA[2]\nPTP XP8\nEND\n"
    res = compensate_program(model, dat, krl, frame="measurement", context=src + _CONFIG)
    assert not res.failed and [t.name for t in res.targets] == ["XP8"]
    assert _changed(dat, res.text) == {3}
    assert any("XP9 (line 2)" in n and "kept" in n for n in res.notes)
    p8, _ = read(res.text, 3)
    (qc,) = controller(model.nominal, [("joint", q8), ("pose", B1 @ p8 @ np.linalg.inv(TL2), {})])
    tcp = real_tcp(model, fk(model.robot_, qc[None])[0], np.linalg.inv(model.nominal.tool) @ TL2)
    assert np.linalg.norm(tcp[:3, 3] - (B1 @ T8)[:3, 3]) * 1e3 < 2e-3
