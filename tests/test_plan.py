"""Measurement planning (hykin.planning, ``hykin plan``): constraints honoured by every planned pose,
selection against naive reference implementations, ordering, forecast properties, CLI."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from cli_run import run as _run

from hykin.calibration.calibrate import calibrate, parameter_names
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk
from hykin.kinematics.robot import Robot
from hykin.planning import Constraints, PlanningError, embed, farthest_point, plan_poses
from hykin.planning.constraints import segment_hits_box
from hykin.planning.criteria import identification_model, scaled_rows
from hykin.planning.forecast import forecast_accuracy
from hykin.planning.order import order_path, path_travel, travel_matrix
from hykin.planning.select import active_poses, d_optimal, i_optimal

DEG = math.pi / 180


def own_robot() -> Robot:
    """A 6R arm not among the presets (own DH, masses), with a tool offset."""
    r = Robot(
        name="test-6r", convention="dh",
        a_m=np.array([0.15, 0.55, 0.09, 0.0, 0.0, 0.0]), alpha_rad=np.array([-90, 0, -90, 90, -90, 0]) * DEG,
        d_m=np.array([0.40, 0.0, 0.0, 0.60, 0.0, 0.10]), theta_rad=np.array([0, -90, 0, 0, 0, 0]) * DEG,
        lower=np.array([-160, -90, -130, -190, -115, -260]) * DEG, upper=np.array([160, 140, 65, 190, 115, 260]) * DEG,
        mass_kg=np.array([40.0, 30.0, 18.0, 6.0, 2.5, 0.8]), com_m=np.zeros((6, 3)), payload_kg=8.0,
    )
    T = np.eye(4)
    T[:3, 3] = [0.03, 0.0, 0.12]
    return r.copy(tool=T)


def _incidence_ref(robot, q, tracker, axis=(0, 0, 1), offset=(0, 0, 0)):
    """Reference line-of-sight angle, pose by pose (independent of the vectorised code)."""
    out = []
    for row in q:
        T = fk(robot, row)
        p = T[:3, 3] + T[:3, :3] @ np.asarray(offset, float)
        n = T[:3, :3] @ np.asarray(axis, float)
        v = np.asarray(tracker) - p
        out.append(math.degrees(math.acos(max(-1.0, min(1.0, float(v @ n) / (np.linalg.norm(v) * np.linalg.norm(n)))))))
    return np.array(out)


def _beam_hits_box_ref(a, b, box, k=2001):
    t = np.linspace(0, 1, k)[:, None]
    pts = a[None] + t * (b - a)[None]
    return bool(np.any(np.all((pts >= box[0]) & (pts <= box[1]), axis=1)))


@pytest.mark.parametrize("robot_name,seed,tracker,max_inc", [
    ("own", 0, (2.0, 0.3, 0.6), 30.0),
    ("own", 1, (-1.5, 1.5, 1.0), 45.0),
    ("ur5", 2, (1.2, -0.5, 0.3), 30.0),
    ("rx160", 3, (0.0, 2.5, 1.5), 40.0),
])
def test_every_planned_pose_has_line_of_sight(robot_name, seed, tracker, max_inc):
    robot = own_robot() if robot_name == "own" else load_robot(robot_name)
    tracker = np.array(tracker)
    # keep-out box between robot and tracker, half-way, off the axis a little
    mid = 0.5 * tracker
    box = np.array([mid - [0.1, 0.1, 0.1], mid + [0.1, 0.1, 0.1]]) + np.array([0.0, 0.05, 0.0])
    axis, offset = (0.0, 0.0, 1.0), (0.0, 0.02, 0.05)
    c = Constraints(tracker_m=tracker, max_incidence_deg=max_inc, keep_out_m=[box], reflector_axis=np.array(axis),
                    reflector_offset_m=np.array(offset), body=False)  # line of sight only (the body: test_plan_safety)
    p = plan_poses(robot, 25, c, seed=seed, pool=4096, core_factor=0.5)
    assert p.q.shape == (25, robot.dof)
    assert np.all((p.q >= robot.lower) & (p.q <= robot.upper))
    ang = _incidence_ref(robot, p.q, tracker, axis, offset)
    assert np.all(ang <= max_inc + 1e-9), ang.max()
    for row in p.q:
        T = fk(robot, row)
        pt = T[:3, 3] + T[:3, :3] @ np.array(offset)
        assert not _beam_hits_box_ref(tracker, pt, box)
        assert not np.all((pt >= box[0]) & (pt <= box[1]))


def test_region_and_cartesian_box_honoured():
    robot = own_robot()
    lo = robot.lower * 0.5
    hi = robot.upper * 0.5
    T = fk(robot, robot.random_joints(2000, np.random.default_rng(0)))
    box = np.array([[0.2, -0.6, 0.0], [1.2, 0.6, 1.2]])
    assert np.mean(np.all((T[:, :3, 3] >= box[0]) & (T[:, :3, 3] <= box[1]), 1)) < 0.9  # the box does cut
    p = plan_poses(robot, 30, Constraints(lower=lo, upper=hi, box_m=box), seed=1, pool=4096, core_factor=0.5)
    assert np.all((p.q >= lo - 1e-12) & (p.q <= hi + 1e-12))
    P = fk(robot, p.q)[:, :3, 3]
    assert np.all((P >= box[0]) & (P <= box[1]))


def test_impossible_constraints_raise_one_line():
    robot = own_robot()
    c = Constraints(tracker_m=np.array([0.0, 0.0, 20.0]), max_incidence_deg=1.0, box_m=np.array([[5, 5, 5], [6, 6, 6.0]]))
    with pytest.raises(PlanningError, match="meet the constraints"):
        plan_poses(robot, 10, c, pool=1024)
    with pytest.raises(PlanningError, match="exceeds the joint limits"):
        plan_poses(robot, 10, Constraints(lower=robot.lower - 1, upper=robot.upper))


def test_segment_box_against_sampling():
    rng = np.random.default_rng(4)
    box = np.array([[-0.2, -0.1, 0.0], [0.3, 0.2, 0.4]])
    a = rng.uniform(-1, 1, (300, 3))
    b = rng.uniform(-1, 1, (300, 3))
    got = segment_hits_box(a, b, box)
    ref = np.array([_beam_hits_box_ref(a[i], b[i], box, 4001) for i in range(300)])
    # sampling can miss a grazing hit; it never finds one the slab test misses
    assert np.all(got[ref]) and np.mean(got == ref) > 0.98 and ref.sum() > 20


def test_d_optimal_matches_naive_greedy():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(60, 3, 7))
    J[::7] *= 3.0
    got = d_optimal(J, 12, prior=1e-3)
    M = 1e-3 * np.eye(7)
    ref = []
    for _ in range(12):
        best, bi = -np.inf, -1
        for i in range(60):
            if i in ref:
                continue
            v = np.linalg.slogdet(M + J[i].T @ J[i])[1]
            if v > best:
                best, bi = v, i
        ref.append(bi)
        M = M + J[bi].T @ J[bi]
    assert got.tolist() == ref


def test_i_optimal_matches_naive_greedy():
    rng = np.random.default_rng(1)
    J = rng.normal(size=(50, 3, 6))
    B = rng.normal(size=(6, 6))
    W = B @ B.T / 6
    got = i_optimal(J, 10, W, prior=1e-2)
    M = 1e-2 * np.eye(6)
    ref = []
    for _ in range(10):
        vals = [np.inf if i in ref else np.trace(W @ np.linalg.inv(M + J[i].T @ J[i])) for i in range(50)]
        bi = int(np.argmin(vals))
        ref.append(bi)
        M = M + J[bi].T @ J[bi]
    assert got.tolist() == ref


def test_identification_model_matches_calibration():
    robot = load_robot("ur5").copy(mass_kg=np.array([3.7, 8.4, 2.3, 1.2, 1.2, 0.2]), payload_kg=2.0)
    q = robot.random_joints(150, np.random.default_rng(1))
    idm = identification_model(robot, q, position_only=True)
    res = calibrate(robot, (q, fk(robot, q)[:, :3, 3]), max_iter=1)
    assert idm.names == [n for n, m in zip(res.names, res.identifiable) if m]  # estimated (identified or correlated)
    assert set(idm.names) <= set(parameter_names(robot))
    # scaled rows: mm of TCP per typical deviation (1 mm for a length -> about 1 mm)
    J = scaled_rows(idm, q[:5])
    k = idm.names.index("base.x")
    assert np.allclose(np.abs(J[:, 0, k]), 1.0)


def test_embed_wraps_full_turn_joints_and_farthest_point_is_maximin():
    robot = own_robot()
    lo, hi = robot.lower, robot.upper
    q = np.zeros((2, 6))
    q[0, 5], q[1, 5] = -math.pi + 0.01, math.pi - 0.01  # joint 6 spans 520 deg: wrapped
    X = embed(robot, q, lo, hi)
    assert np.linalg.norm(X[0] - X[1]) == pytest.approx(0.02 / (2 * math.pi), rel=1e-3)
    q[1, 5] = q[0, 5] + 2 * math.pi
    X = embed(robot, q, lo, hi)
    assert np.linalg.norm(X[0] - X[1]) < 1e-12
    # greedy maximin against a naive loop
    rng = np.random.default_rng(3)
    P = rng.random((200, 3))
    got = farthest_point(P, 15, chosen=np.array([5]))
    sel = [5]
    for _ in range(15):
        d = np.min(np.linalg.norm(P[:, None] - P[sel][None], axis=2), axis=1)
        d[sel] = -1
        sel.append(int(np.argmax(d)))
    assert got.tolist() == sel[1:]


def test_order_path_short_and_a_permutation():
    rng = np.random.default_rng(2)
    x = rng.permutation(np.linspace(0, 3, 40))
    q = np.stack([x, 0.5 * x], 1)
    v = np.array([1.0, 0.25])  # joint 2 slower: max(|dx|, 0.5|dx|/0.25) = 2|dx|
    path = order_path(q, v, start=np.array([0.0, 0.0]))
    assert sorted(path.tolist()) == list(range(40))
    tr = path_travel(q[path], v, dwell_s=2.0)
    assert tr["move_s"] == pytest.approx(2 * 3.0)  # optimal: monotone along the line
    assert tr["joint_rad"] == pytest.approx(1.5 * 3.0)
    assert tr["total_s"] == pytest.approx(6.0 + 80.0)
    # random 4-D points: 2-opt never longer than the input order, and far shorter
    Q = rng.uniform(-2, 2, (150, 4))
    p2 = order_path(Q, 1.0)
    D = travel_matrix(Q, 1.0)
    assert D[p2[:-1], p2[1:]].sum() < 0.5 * D[np.arange(149), np.arange(1, 150)].sum()


def test_forecast_parameter_part_scales_with_repetition():
    robot = own_robot()
    p = plan_poses(robot, 40, seed=0, pool=2048, core_factor=0.5)
    q2 = np.vstack([p.nested(), p.nested()])  # the same 40 poses measured twice
    qt = robot.random_joints(300, np.random.default_rng(5))
    fc = forecast_accuracy(p.id_model, q2, qt, [40, 80], noise_mm=0.02, unmodelled_mm=0.0)
    assert fc.param_mm[0] / fc.param_mm[1] == pytest.approx(math.sqrt(2), rel=1e-6)
    fc2 = forecast_accuracy(p.id_model, q2, qt, [40], noise_mm=0.04, unmodelled_mm=0.0)
    assert fc2.param_mm[0] == pytest.approx(2 * fc.param_mm[0], rel=1e-9)
    assert fc.calibrated_mm[0] > fc.hybrid_mm[0] * 0.999


def test_d_optimal_core_beats_random_on_logdet():
    robot = own_robot()
    p = plan_poses(robot, 30, Constraints(body=False), seed=0, pool=4096)  # the criterion only (body: test_plan_safety)
    J = scaled_rows(p.id_model, robot.random_joints(30, np.random.default_rng(7)))
    A = J.reshape(-1, J.shape[-1])
    assert p.criteria["logdet"] > np.linalg.slogdet(A.T @ A)[1] + 5.0  # e^5 = 150x larger det




def test_cli_plan_writes_ordered_joints_with_line_of_sight(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    code, _, se = _run(["plan", "ur5", "-n", "20", "-o", str(out), "--seed", "3", "--tracker", "1200,-300,400",
                         "--length-unit", "mm", "--max-incidence", "40", "--pool", "2048",
                         "--region", "-90:90,:,:,:,:,:", "--no-body-check"], capsys)
    assert code == 0, se
    from hykin.io.dataset_files import read_joints

    q, extra = read_joints(out)
    assert q.shape == (20, 6)
    assert np.all(np.abs(q[:, 0]) <= math.pi / 2 + 1e-12)
    ang = _incidence_ref(load_robot("ur5"), q, np.array([1.2, -0.3, 0.4]))
    assert np.all(ang <= 40 + 1e-9) and np.allclose(ang, extra["incidence_deg"])
    assert extra["step"].tolist() == list(range(1, 21))
    assert "joint travel" in se


def test_cli_plan_bad_input_one_line_nothing_written(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    code, _, se = _run(["plan", "ur5", "-n", "10", "-o", str(out), "--region", "-90:90,:"], capsys)
    assert code == 2 and se.strip().count("\n") == 0 and "region" in se and not out.exists()
    code, _, se = _run(["plan", "ur5", "-n", "10", "-o", str(out), "--tracker", "1,2"], capsys)
    assert code == 2 and "--tracker" in se and not out.exists()
    code, _, se = _run(["plan", "-n", "10", "-o", str(out)], capsys)
    assert code == 2 and "ROBOT" in se and not out.exists()


def test_cli_plan_report_prints_table(tmp_path, capsys):
    code, so, se = _run(["plan", "ur5", "-n", "30", "--report", "--pool", "2048", "--noise-mm", "0.02",
                         "--report-max", "300"], capsys)
    assert code == 0, se
    assert "calibrated mm" in so and "hybrid mm" in so
    rows = [ln.split() for ln in so.splitlines() if ln.strip()[:1].isdigit()]
    cal = [float(r[2]) for r in rows]
    assert len(rows) >= 3 and all(a >= b - 1e-9 for a, b in itertools.pairwise(cal))  # more poses, no worse


def test_active_poses_go_where_the_model_is_uncertain(tmp_path, capsys):
    from hykin.hybrid.model import HybridModel
    from hykin.sim.presets import virtual_preset
    from hykin.sim.simulate import simulate

    vr = virtual_preset("ur10-virtual")
    rob = vr.nominal
    lo, hi = rob.lower.copy(), rob.upper.copy()
    lo[0], hi[0] = -0.5, 0.5  # trained on a narrow band of joint 1 only
    q = rob.random_joints(300, np.random.default_rng(0))
    q[:, 0] = np.random.default_rng(1).uniform(-0.5, 0.5, 300)
    m = HybridModel(rob, recipe_kw={"max_epochs": 5, "batch_size": 64}, seed=0).fit(simulate(vr, q, rng=0), progress=False)
    p = active_poses(m, 12, Constraints(lower=np.maximum(rob.lower, -2.0), upper=np.minimum(rob.upper, 2.0), body=False),
                     pool=2048)
    outside = np.abs(p.q[:, 0]) > 0.5
    assert outside.mean() >= 0.75  # the training data are thinnest (none) outside the trained band
    assert p.info["n_existing"] == 300
    # a batch, not twelve copies of the best candidate
    X = embed(rob, p.q, np.maximum(rob.lower, -2.0), np.minimum(rob.upper, 2.0))
    d = np.linalg.norm(X[:, None] - X[None], axis=2) + np.eye(12) * 1e9
    assert d.min() > 0.05
    path = tmp_path / "m.hykin"
    m.save(path)
    out = tmp_path / "next.csv"
    code, so, se = _run(["plan", "--for-model", str(path), "-n", "8", "-o", str(out), "--pool", "1024", "--no-body-check", "--report",
                         "--report-max", "100"], capsys)
    assert code == 0, se
    assert "hybrid mm" in so
    from hykin.io.dataset_files import read_joints

    assert read_joints(out)[0].shape == (8, 6)


def _deficit_ref(X_pool, X_have, n, have_weight, weight, neighbours):
    """Density-deficit augmentation written out with dense distance matrices (reference for
    :func:`hykin.planning.coverage.deficit_select`; the rules restated from its docstring)."""
    M = len(X_pool)
    total = len(X_have) * have_weight + n
    k = int(np.clip(round(neighbours * M / total), 2, M - 1))
    D = np.linalg.norm(X_pool[:, None] - X_pool[None], axis=2)
    probe = np.random.default_rng(0).permutation(M)[: min(M, 256)]
    r = float(np.median(np.sort(D[probe], axis=1)[:, k]))
    expected = (D <= r).sum(1) * total / M
    observed = have_weight * (np.linalg.norm(X_pool[:, None] - X_have[None], axis=2) <= r).sum(1)
    picked = []
    while len(picked) < n:
        score = (expected - observed) * weight
        score[picked] = -np.inf
        j = int(np.argmax(score))
        picked.append(j)
        observed = observed + (D[:, j] <= r)
    return np.array(picked)


def test_deficit_select_matches_reference_and_fills_the_empty_part():
    from hykin.planning.coverage import deficit_select

    rng = np.random.default_rng(5)
    pool = rng.random((600, 3))
    have = rng.random((80, 3)) * [0.5, 1.0, 1.0]  # existing design: the half x < 0.5 only
    w = rng.uniform(0.5, 1.5, 600)
    got = deficit_select(pool, have, 40, have_weight=2.0, weight=w, neighbours=12)
    np.testing.assert_array_equal(got, _deficit_ref(pool, have, 40, 2.0, w, 12))
    assert len(set(got.tolist())) == 40
    # 160 existing (weighted) in one half, 40 new: the new poses belong in the empty half (a few fill
    # holes of the random existing design, or land just short of the border their balls straddle)
    assert (pool[got, 0] > 0.45).mean() >= 0.8


def test_deficit_select_does_not_crowd_the_boundary():
    from scipy.stats import qmc

    from hykin.planning.coverage import deficit_select

    pool = qmc.Sobol(4, seed=6).random(4096)  # a uniform pool, as in active_poses
    got = deficit_select(pool, np.zeros((0, 4)), 100)
    near = lambda X: (np.minimum(X, 1 - X).min(1) < 0.1).mean()
    # farthest-point designs put most points on the boundary of a box; the deficit rule follows the pool
    assert near(pool[got]) < 1.3 * near(pool)
    assert near(pool[farthest_point(pool, 100)]) > 1.3 * near(pool)


def _cd2_ref(x):
    """Squared centred L2 discrepancy, Hickernell's closed form written out (reference)."""
    n, d = x.shape
    a = np.abs(x - 0.5)
    t2 = 2.0 / n * np.prod(1 + 0.5 * a - 0.5 * a**2, axis=1).sum()
    t3 = np.prod(1 + 0.5 * a[:, None] + 0.5 * a[None] - 0.5 * np.abs(x[:, None] - x[None]), axis=2).sum() / n**2
    return (13 / 12) ** d - t2 + t3


def test_coverage_measures_against_references():
    from scipy.stats import kstest

    from hykin.planning.coverage import centred_discrepancy, hole_fraction, marginal_ks

    rng = np.random.default_rng(5)
    u = rng.random((40, 4))
    assert centred_discrepancy(u) == pytest.approx(_cd2_ref(u), rel=1e-12)
    assert marginal_ks(u) == pytest.approx(max(kstest(u[:, j], "uniform").statistic for j in range(4)), rel=1e-12)
    # a Latin hypercube column (one point per stratum, at its centre) has KS distance 1/(2n)
    lhs = (np.argsort(rng.random((50, 3)), axis=0) + 0.5) / 50
    assert marginal_ks(lhs) == pytest.approx(0.01, abs=1e-12)
    # holes: a 2-D grid design with a 0.3 x 0.3 block removed; reference points in the block's middle
    # (farther than the tolerance from every design point) are holes, points on the grid are not
    g = (np.arange(21) / 20.0)
    grid = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    keep = ~np.all((grid > 0.35) & (grid < 0.65), axis=1)
    design = grid[keep]
    ref = np.array([[0.5, 0.5], [0.48, 0.52], [0.1, 0.1], [0.0, 1.0], [0.925, 0.3]])
    # reference rule written out: tolerance max(2 x p95 spacing, 1/47); spacing of this grid is 0.05
    d = np.sqrt(((ref[:, None] - design[None]) ** 2).sum(-1)).min(1)
    expect = np.mean(d > max(2 * 0.05, 1 / 47))
    assert expect == pytest.approx(0.4)
    assert hole_fraction(design, ref) == pytest.approx(expect)
    assert hole_fraction(grid, ref) == 0.0


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])
def test_plan_is_more_uniform_than_random_and_stratified(seed):
    """The planned poses cover the working region more evenly than uniform random poses of the same
    number, by the coverage measures of hykin.planning.coverage (measured at 256 poses: discrepancy
    7-9x lower, largest marginal KS distance 4x lower), and every joint's marginal is stratified."""
    from hykin.planning.coverage import coverage_report, unit_coordinates
    from hykin.sim.sampling import random as random_joints

    r = own_robot()
    lo = np.array([-120, -60, -100, -180, -100, -180]) * DEG
    hi = np.array([120, 110, 50, 180, 100, 180]) * DEG
    n = 256
    p = plan_poses(r, n, Constraints(lower=lo, upper=hi), seed=seed, position_only=False)
    assert np.all((p.q >= lo - 1e-12) & (p.q <= hi + 1e-12))
    cr = p.criteria
    for k in range(3):  # several random sets: the plan beats each one, not only on average
        qr = random_joints(r, n, np.random.default_rng([seed, k, 7]), lower=lo, upper=hi)
        rr = coverage_report(qr, lo, hi)
        assert cr["discrepancy_cd"] < rr["discrepancy_cd"] / 3
        assert cr["marginal_ks"] < rr["marginal_ks"] / 2
    ref = coverage_report(p.q, lo, hi, seed=seed)
    assert ref["discrepancy_cd"] == pytest.approx(cr["discrepancy_cd"])
    # marginal stratification: 8 equal bins per joint hold 32 +- 4 poses each (random: 17..43 measured)
    u = unit_coordinates(p.q, lo, hi)
    counts = np.stack([np.bincount(np.minimum((u[:, j] * 8).astype(int), 7), minlength=8) for j in range(r.dof)])
    assert counts.min() >= 28 and counts.max() <= 36, counts


def test_travel_from_is_a_row_of_the_travel_matrix():
    """The detour search takes move times from two poses to the whole via pool without the (V, V) matrix
    (probe report s40: 15 GB for a 40-pose plan with the body check). Reference: travel_matrix's row."""
    from hykin.planning.order import travel_from, travel_matrix

    rng = np.random.default_rng(3)
    q = rng.uniform(-7.0, 7.0, (50, 6))
    v = rng.uniform(0.5, 3.0, 6)
    turns = np.array([True, False, False, True, False, True])
    for tw in (None, turns):
        np.testing.assert_allclose(travel_from(q[0], q[1:], v, tw), travel_matrix(q, v, tw)[0, 1:], rtol=0, atol=1e-12)
