"""Safe plans and plans as robot programs (issue "From a plan to the robot and back").

References are independent of the planner's vectorised code: capsule clearances by dense sampling
of the segments, and a stand-in controller per language that parses the program with its own
regular expressions and replays the joint moves in order."""

from __future__ import annotations

import re

import numpy as np
import pytest
from cli_run import run as _run

from hykin.kinematics.robot import Robot
from hykin.planning import Constraints, plan_poses
from hykin.planning.bodies import body_segments, segment_distance
from hykin.planning.moves import interpolate_moves
from hykin.planning.programs import ProgramSettings, plan_program

DEG = np.pi / 180


def arm6() -> Robot:
    return Robot(name="own-6r", convention="dh", a_m=[0.12, 0.5, 0.08, 0, 0, 0], alpha_rad=np.array([-90, 0, -90, 90, -90, 0]) * DEG,
                 d_m=[0.45, 0, 0, 0.55, 0, 0.09], theta_rad=np.array([0, -90, 0, 0, 0, 0]) * DEG,
                 lower=np.array([-170, -100, -140, -185, -120, -350]) * DEG, upper=np.array([170, 145, 70, 185, 120, 350]) * DEG)


def arm7() -> Robot:
    return Robot(name="own-7r", convention="dh", a_m=np.zeros(7), alpha_rad=np.array([-90, 90, 90, -90, -90, 90, 0]) * DEG,
                 d_m=[0.36, 0, 0.42, 0, 0.40, 0, 0.13], theta_rad=np.zeros(7),
                 lower=np.array([-168, -118, -168, -118, -168, -118, -173]) * DEG,
                 upper=np.array([168, 118, 168, 118, 168, 118, 173]) * DEG)


def ur_like() -> Robot:
    return Robot(name="own-ur", convention="dh", a_m=[0, -0.45, -0.40, 0, 0, 0], alpha_rad=np.array([90, 0, 0, 90, -90, 0]) * DEG,
                 d_m=[0.10, 0, 0, 0.12, 0.10, 0.09], theta_rad=np.zeros(6),
                 lower=np.full(6, -2 * np.pi), upper=np.full(6, 2 * np.pi))


def _clearances_ref(robot, q, radii, pairs, floor, floor_bodies, box):
    """Dense-sampling reference: (min pair clearance, min floor clearance, any capsule in the box)."""
    seg, body = body_segments(robot, q)
    t = np.linspace(0, 1, 60)[:, None]
    pts = seg[:, :, 0, None] + t * (seg[:, :, 1, None] - seg[:, :, 0, None])  # (N, S, 60, 3)
    pair_min = np.inf
    for i, j in pairs:
        A = pts[:, body == i].reshape(len(q), -1, 3)
        B = pts[:, body == j].reshape(len(q), -1, 3)
        d = np.linalg.norm(A[:, :, None] - B[:, None], axis=-1).min(axis=(1, 2)) - radii[i] - radii[j]
        pair_min = min(pair_min, float(d.min()))
    fl = np.inf
    for b in np.flatnonzero(floor_bodies):
        fl = min(fl, float((pts[:, body == b, :, 2].min() - radii[b]) - floor))
    inside = False
    for b in range(1, len(radii)):
        P = pts[:, body == b].reshape(-1, 3)
        inside |= bool(np.any(np.all((P > box[0] + 1e-9) & (P < box[1] - 1e-9), axis=1)))
    return pair_min, fl, inside


def test_segment_distance_against_dense_sampling():
    rng = np.random.default_rng(3)
    a0, a1, b0, b1 = (rng.normal(size=(300, 3)) for _ in range(4))
    b1[:30] = b0[:30]  # point vs segment
    a1[30:60] = a0[30:60]
    b1[60:90] = b0[60:90] + 0.6 * (a1[60:90] - a0[60:90])  # parallel
    d = segment_distance(a0, a1, b0, b1)
    t = np.linspace(0, 1, 401)
    pa = a0[:, None] + t[None, :, None] * (a1 - a0)[:, None]
    pb = b0[:, None] + t[None, :, None] * (b1 - b0)[:, None]
    ref = np.concatenate([np.linalg.norm(pa[k:k + 20, :, None] - pb[k:k + 20, None], axis=-1).min(axis=(1, 2))
                          for k in range(0, len(pa), 20)])
    assert np.all(d <= ref + 1e-12)  # never above a sampled distance
    assert np.all(ref - d < 5e-3)  # and within the sampling resolution of the true minimum


def test_interpolated_moves_are_fine_and_between_the_poses():
    q = np.array([[0.0, 0.0], [0.5, -0.1], [0.52, 0.3]])
    qi, mv = interpolate_moves(q, step_rad=np.radians(2.0))
    assert np.all(np.diff(mv) >= 0)
    full = np.vstack([q[0], *[np.vstack([qi[mv == k], q[k + 1]]) for k in range(2)]])
    assert np.max(np.abs(np.diff(full, axis=0))) <= np.radians(2.0) + 1e-12
    # every intermediate lies on its segment
    for k in range(2):
        d = q[k + 1] - q[k]
        s = (qi[mv == k] - q[k]) @ d / (d @ d)
        assert np.allclose(q[k] + s[:, None] * d, qi[mv == k]) and np.all((s > 0) & (s < 1))


@pytest.mark.parametrize("make,seed,n,boxed", [
    (arm6, 0, 12, True),
    pytest.param(arm6, 0, 30, True, marks=pytest.mark.slow),
    pytest.param(arm7, 1, 30, True, marks=pytest.mark.slow),
    # a UR-like arm (every joint ±360°) with a box beside it: up to 23 of 30 poses are dropped (no detour found)
    pytest.param(ur_like, 2, 30, False, marks=pytest.mark.slow),
])
def test_planned_poses_and_moves_clear_floor_boxes_and_body(make, seed, n, boxed):
    robot = make()
    box = np.array([[0.35, -0.25, 0.0], [0.65, 0.25, 0.35]]) if boxed else np.array([[5.0, 5, 5], [6.0, 6, 6]])
    c = Constraints(floor_z_m=0.0, keep_out_m=[box])
    p = plan_poses(robot, n, c, seed=seed, pool=1024 if n < 20 else 2048)
    assert len(p.q) == n - p.info["dropped"]
    assert p.info["dropped"] <= 2
    mv = p.moves
    assert np.allclose(mv.q[mv.measure], p.q)
    cc = c.check(robot)
    qi, _ = interpolate_moves(mv.q, step_rad=np.radians(2.0))
    Q = np.vstack([mv.q, qi])
    sub = Q[np.random.default_rng(seed).choice(len(Q), size=min(len(Q), 400), replace=False)]
    pair_min, floor_min, inside = _clearances_ref(robot, sub, cc.bodies.radii_m, cc.bodies.pairs, 0.0,
                                                  cc.bodies.floor_bodies, box)
    assert pair_min >= -1e-3 * cc.bodies.radii_m.max()  # sampling of the reference: 1/60 of a segment
    assert floor_min >= -1e-9
    assert not inside
    # and joint limits hold everywhere
    assert np.all(Q >= robot.lower - 1e-12) and np.all(Q <= robot.upper + 1e-12)


def test_without_body_check_poses_hit_the_floor_and_the_body():
    robot = arm6()
    c = Constraints(floor_z_m=0.0).check(robot)
    p_free = plan_poses(robot, 100, Constraints(body=False), seed=0, pool=1024)
    pair_min, floor_min, _ = _clearances_ref(robot, p_free.q, c.bodies.radii_m, c.bodies.pairs, 0.0,
                                             c.bodies.floor_bodies, np.array([[9, 9, 9], [10, 10, 10.0]]))
    assert floor_min < 0 or pair_min < 0  # the check matters on this robot


# --------------------------------------------------------------------------- stand-in controllers


def _replay_urscript(text):
    moves, events = [], []
    for line in text.splitlines():
        line = line.split("#")[0].strip()
        m = re.match(r"movej\(\[([^\]]*)\]\s*,\s*a=([\d.eE+-]+)\s*,\s*v=([\d.eE+-]+)\)$", line)
        if m:
            moves.append([float(x) for x in m.group(1).split(",")])
        elif re.match(r"set_standard_digital_out\(\d+,\s*True\)$", line):
            events.append(len(moves) - 1)
        elif line and not re.match(r"(def \w+\(\):|end|sleep\([\d.]+\)|set_standard_digital_out\(\d+,\s*False\))$", line):
            raise AssertionError(f"URScript line not understood: {line!r}")
    return np.array(moves), events


def _replay_krl(src, dat):
    pts = {}
    for line in dat.splitlines():
        m = re.match(r"DECL E6AXIS (\w+)=\{(.*)\}$", line.strip())
        if m:
            vals = dict(re.findall(r"([AE]\d)\s+(-?[\d.]+)", m.group(2)))
            pts[m.group(1)] = [float(vals[f"A{i}"]) for i in range(1, 7)]
    assert dat.strip().splitlines()[1].startswith("DEFDAT") and dat.strip().endswith("ENDDAT")
    moves, events = [], []
    for line in src.splitlines():
        line = line.split(";")[0].strip()
        m = re.match(r"PTP (\w+)$", line)
        if m:
            moves.append(pts[m.group(1)])
        elif re.match(r"\$OUT\[\d+\]=TRUE$", line):
            events.append(len(moves) - 1)
        elif line and not re.match(r"(&ACCESS \w+|DEF \w+\( \)|END|\$VEL_AXIS\[\d\]=[\d.]+|WAIT SEC [\d.]+|\$OUT\[\d+\]=FALSE)$", line):
            raise AssertionError(f"KRL line not understood: {line!r}")
    return np.radians(np.array(moves)), events


def _replay_rapid(text):
    moves, events = [], []
    for line in text.splitlines():
        line = line.split("!")[0].strip()
        m = re.match(r"MoveAbsJ \[\[([^\]]*)\],\[9E9(?:,9E9){5}\]\]\\NoEOffs, vPlan, fine, tool0;$", line)
        if m:
            moves.append([float(x) for x in m.group(1).split(",")])
        elif re.match(r"SetDO \w+, 1;$", line):
            events.append(len(moves) - 1)
        elif line and not re.match(r"(MODULE \w+|ENDMODULE|PROC main\(\)|ENDPROC|CONST speeddata vPlan := \[[\d., ]+\];|"
                                   r"WaitTime [\d.]+;|SetDO \w+, 0;)$", line):
            raise AssertionError(f"RAPID line not understood: {line!r}")
    return np.radians(np.array(moves)), events


def test_programs_visit_exactly_the_planned_joints_in_order():
    robot = arm6()
    p = plan_poses(robot, 12, Constraints(floor_z_m=0.0), seed=4, pool=1024)
    signs = np.array([-1, 1, 1, -1, 1, -1.0])
    offs = np.radians([0, 90, -90, 0, 0, 0])
    expect = signs * p.moves.q + offs
    for kind, trig in (("urscript", "do:2"), ("krl", "do:7"), ("rapid", "do:doMeasure")):
        s = ProgramSettings(speed_rad_s=0.5, dwell_s=2.0, trigger=trig, axis_signs=signs, axis_offsets_rad=offs,
                            expected_s=123.0)
        texts = plan_program(kind, p.moves.q, p.moves.measure, robot, s)
        if kind == "urscript":
            got, ev = _replay_urscript(texts[".script"])
            tol = 1e-8
        elif kind == "krl":
            got, ev = _replay_krl(texts[".src"], texts[".dat"])
            tol = np.radians(1e-5)
        else:
            got, ev = _replay_rapid(texts[".mod"])
            tol = np.radians(1e-5)
        assert got.shape == expect.shape
        assert np.max(np.abs(got - expect)) <= tol
        assert ev == list(np.flatnonzero(p.moves.measure))  # one measurement at each measured pose, none at vias
        assert "expected measuring time: 2.0 min" in next(iter(texts.values()))


def test_cli_plan_outputs_by_suffix(tmp_path, capsys):
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text("""name = "arm-deg"
convention = "dh"
length_unit = "mm"
angle_unit = "deg"
""" + "".join(f"""[[joints]]
a = {a}
alpha = {al}
d = {d}
theta = {th}
min = -150
max = 150
""" for a, al, d, th in [(120, -90, 450, 0), (500, 0, 0, -90), (80, -90, 0, 0), (0, 90, 550, 0), (0, -90, 0, 0), (0, 0, 90, 0)]))
    rc, out, err = _run(["plan", str(robot_file), "-n", "15", "--pool", "1000", "-o", str(tmp_path / "p.csv"), "--floor", "0",
                         "--length-unit", "mm"], capsys)
    assert rc == 0, err
    assert "line of sight to the tracker was not checked" in out + err
    head = (tmp_path / "p.csv").read_text().splitlines()[0]
    assert head.startswith("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,step,measure")
    rc, out, err = _run(["plan", str(robot_file), "-n", "15", "--pool", "1000", "-o", str(tmp_path / "p.txt")], capsys)
    assert rc != 0 and "unknown output type '.txt'" in err and not (tmp_path / "p.txt").exists()
    rc, out, err = _run(["plan", str(robot_file), "-n", "15", "--pool", "1000", "-o", str(tmp_path / "cell.src"), "--trigger", "di:3", "--no-body-check"], capsys)
    assert rc == 0, err
    assert (tmp_path / "cell.src").read_bytes().startswith(b"&ACCESS RVP\r\nDEF cell( )")
    assert "WAIT FOR $IN[3]" in (tmp_path / "cell.src").read_text()
    assert "DEFDAT cell" in (tmp_path / "cell.dat").read_text()
    rc, out, err = _run(["plan", str(robot_file), "-n", "15", "--pool", "1000", "-o", str(tmp_path / "m.mod"), "--trigger", "do:4", "--no-body-check"], capsys)
    assert rc != 0 and "signal name" in err and not (tmp_path / "m.mod").exists()
