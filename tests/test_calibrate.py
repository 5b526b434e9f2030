"""Parametric calibration (hykin.calibrate): exact recovery on noise-free virtual robots,
identifiability against the Everett–Hsu–Roth parameter count, redundancy detection, standard
deviations against injected noise, analytic Jacobian against finite differences, real UR5 data."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from hykin.calibration.calibrate import (
    CalibrationError,
    apply_deviations,
    calibrate,
    calibrated_fk,
    identification_jacobian,
    parameter_names,
)
from hykin.geometry import se3
from hykin.io.robot_file import load_robot
from hykin.kinematics.compliance import compliance_of, compliant_fk
from hykin.kinematics.robot import dh_to_mdh

UR5_DIR = Path(os.environ.get("HYKIN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")) / "serial-robots-ur5" / "UR5"
UNIT = {"m": 1e-3, "rad": 1e-3, "c": 1e-6}  # typical deviation per unit kind


def _kind(name: str) -> str:
    if name.startswith("c") and name[1:].isdigit():
        return "c"
    f = name.split(".")[-1]
    if f in ("x", "y", "z") or name.rstrip("0123456789") in ("a", "d"):
        return "m"
    return "rad"


def _rx160(stiff=True):
    """RX160 with a TCP offset, masses, a 20 kg payload and industrial joint stiffness."""
    r = load_robot("rx160").copy(tool=se3.trans(0.05, 0.0, 0.15), payload_kg=20.0)
    if stiff:
        r = r.copy(stiffness_nm_per_rad=np.array([4e5, 3e5, 2e5, 1e5, 1e5, 5e4]))
    return r


def _random_truth(robot, rng, names=None, mask=None, c_rel=0.3):
    """Random deviations (up to 1 mm / 1 mrad = 0.057 deg) on ``names`` (default all candidates)."""
    names = parameter_names(robot) if names is None else names
    dev = {}
    c0 = compliance_of(robot)
    for k, n in enumerate(names):
        if mask is not None and not mask[k]:
            continue
        kind = _kind(n)
        if kind == "c":
            j = int(n[1:]) - 1
            dev[n] = c_rel * c0[j] * rng.uniform(-1, 1)
        else:
            dev[n] = UNIT[kind] * rng.uniform(0.1, 1.0) * rng.choice([-1, 1])
    return apply_deviations(robot, dev), dev


def _pose_err(Ta, Tb):
    return se3.pose_error(Ta, Tb)


# --------------------------------------------------------------------------- exact recovery


def test_rx160_noise_free_full_calibration_recovers_truth():
    rng = np.random.default_rng(0)
    nom = _rx160()
    truth, _ = _random_truth(nom, rng)  # every parameter perturbed, redundant ones included
    q = nom.random_joints(1200, rng)
    res = calibrate(nom, (q, compliant_fk(truth, q)))
    assert res.converged, res.message
    qt = nom.random_joints(2000, rng)
    pe, ae = _pose_err(calibrated_fk(res.robot, qt), compliant_fk(truth, qt))
    pe0, _ = _pose_err(compliant_fk(nom, qt), compliant_fk(truth, qt))
    assert pe0.mean() > 1.0  # the truth is mm away from the nominal model
    assert pe.max() < 1e-3  # < 1 µm on held-out samples
    assert ae.max() < 1e-5  # < 1e-5 deg
    # compliance of joints 2..6 recovered (joint 1 is vertical: no gravity torque, unidentifiable)
    c_true, c_est = compliance_of(truth), compliance_of(res.robot)
    np.testing.assert_allclose(c_est[1:], c_true[1:], rtol=1e-3)
    ident = dict(zip(res.names, res.identifiable))
    assert not ident["c1"] and not ident["theta1"] and not ident["d1"]
    assert res.after["pos_max_mm"] < 1e-3 and res.before["pos_mean_mm"] > 1.0


def test_exact_parameter_recovery_in_identifiable_subspace():
    """Truth deviations only on the identifiable parameters: values are recovered to rounding."""
    rng = np.random.default_rng(1)
    nom = _rx160()
    q = nom.random_joints(1000, rng)
    probe = calibrate(nom, (q, compliant_fk(nom, q)), max_iter=1)
    truth, dev = _random_truth(nom, rng, probe.names, probe.identifiable)
    res = calibrate(nom, (q, compliant_fk(truth, q)))
    np.testing.assert_array_equal(res.identifiable, probe.identifiable)
    for n, v in dev.items():
        tol = 1e-9 * UNIT[_kind(n)]
        assert abs(res.value(n) - v) < tol, (n, res.value(n), v)
    assert np.all(res.values[~res.identifiable] == 0)
    # held at prior: the prior's std (nan where the prior is uninformative)
    held = ~res.identifiable
    np.testing.assert_array_equal(res.std[held], np.where(np.isfinite(res.prior_std[held]), res.prior_std[held], np.nan))


def test_mdh_robot_calibrates_and_detects_base_redundancy():
    rng = np.random.default_rng(2)
    for stiff, tol_mm, tol_deg in ((False, 1e-6, 1e-8), (True, 1e-2, 1e-3)):
        nom = dh_to_mdh(_rx160(stiff=stiff))
        truth, _ = _random_truth(nom, rng)
        q = nom.random_joints(1500, rng)
        res = calibrate(nom, (q, compliant_fk(truth, q)))
        qt = nom.random_joints(1000, rng)
        pe, ae = _pose_err(calibrated_fk(res.robot, qt), compliant_fk(truth, qt))
        # Rigid: exact. Compliant: MDH alpha1/beta1 tilt joint 1 against the base frame, in which
        # gravity is given; merged into the base frame they tilt gravity by ~1 mrad, which changes
        # the deflection by ~1e-3 of itself (a few µm). Kinematically that split is unidentifiable.
        assert pe.max() < tol_mm and ae.max() < tol_deg, (stiff, pe.max(), ae.max())
        ident = dict(zip(res.names, res.identifiable))
        # MDH joint 1 acts in the base frame: alpha1, a1, theta1, d1 (and beta1) are base parameters
        for n in ("alpha1", "a1", "theta1", "d1", "beta1"):
            assert not ident[n], n
        n_geo = sum(m for n, m in zip(res.names, res.identifiable) if _kind(n) != "c")
        assert n_geo == 30  # 4R + 2P + 6 (Everett, Hsu & Roth 1987)


def test_urdf_robot_origin_twists():
    from hykin.io.urdf import load_urdf_string, robot_to_urdf

    rng = np.random.default_rng(3)
    dh = load_robot("ur5").copy(tool=se3.trans(0.02, 0.01, 0.1))
    nom = load_urdf_string(robot_to_urdf(dh))
    assert nom.convention == "urdf"
    q = nom.random_joints(1500, rng)
    np.testing.assert_allclose(compliant_fk(nom, q), compliant_fk(dh, q), atol=1e-12)
    truth, _ = _random_truth(nom, rng)
    res = calibrate(nom, (q, compliant_fk(truth, q)), compliance=False)
    assert res.converged
    n_geo = int(res.identifiable.sum())
    assert n_geo == 30  # 6 base + 6 tool + 6 x 6 origins, of which 4R + 2P + 6 identifiable
    qt = nom.random_joints(1000, rng)
    pe, ae = _pose_err(calibrated_fk(res.robot, qt), compliant_fk(truth, qt))
    assert pe.max() < 1e-3 and ae.max() < 1e-5


def test_prismatic_scara_dh_and_mdh():
    """R-R-P-R SCARA (all axes parallel): exact, and 4R + 2P + 6 = 20 parameters identifiable."""
    from hykin.kinematics.robot import Robot

    scara = Robot(name="scara", convention="dh", a_m=[0.4, 0.3, 0.0, 0.0], alpha_rad=[0, np.pi, 0, 0],
                  d_m=[0.3, 0, 0.0, 0.05], theta_rad=[0, 0, 0, 0], lower=[-2, -2, 0.0, -3], upper=[2, 2, 0.2, 3],
                  joint_type=("revolute", "revolute", "prismatic", "revolute"), tool=se3.trans(0.03, 0.0, 0.05))
    rng = np.random.default_rng(13)
    for nom in (scara, dh_to_mdh(scara)):
        names = parameter_names(nom, compliance=False)
        truth = apply_deviations(nom, {n: rng.uniform(-1, 1) * 1e-3 for n in names})
        q = nom.random_joints(400, rng)
        res = calibrate(nom, (q, compliant_fk(truth, q)), compliance=False)
        assert int(res.identifiable.sum()) == 20
        qt = nom.random_joints(300, rng)
        pe, ae = _pose_err(calibrated_fk(res.robot, qt), compliant_fk(truth, qt))
        assert pe.max() < 1e-8 and ae.max() < 1e-9


# --------------------------------------------------------------------------- parallel axes, position only


def test_ur10_parallel_axes_need_beta():
    rng = np.random.default_rng(4)
    nom = load_robot("ur10").copy(payload_kg=5.0, tool=se3.trans(0.0, 0.03, 0.1),
                                  stiffness_nm_per_rad=np.array([3e5, 2e5, 1e5, 5e4, 5e4, 5e4]))
    names = parameter_names(nom)
    assert "beta2" in names and "beta3" in names and "beta1" not in names  # alpha2 = alpha3 = 0
    truth, _ = _random_truth(nom, rng)
    q = nom.random_joints(1000, rng)
    T = compliant_fk(truth, q)
    qt = nom.random_joints(1000, rng)
    Tt = compliant_fk(truth, qt)
    res = calibrate(nom, (q, T))
    pe, ae = _pose_err(calibrated_fk(res.robot, qt), Tt)
    assert pe.max() < 1e-3 and ae.max() < 1e-5
    ident = dict(zip(res.names, res.identifiable))
    assert ident["beta2"] and ident["beta3"]
    # without beta, plain DH cannot follow a tilt between parallel axes (first order)
    no_beta = calibrate(nom, (q, T), params=[n for n in names if not n.startswith("beta")])
    pe_nb, _ = _pose_err(calibrated_fk(no_beta.robot, qt), Tt)
    assert pe_nb.mean() > 100 * max(pe.mean(), 1e-6) and pe_nb.mean() > 0.01


def test_position_only_data():
    rng = np.random.default_rng(5)
    nom = _rx160()
    truth, _ = _random_truth(nom, rng)
    q = nom.random_joints(1000, rng)
    # rank identifiability (no model-error floor): c6 moves these noise-free points by ~1 µm only
    res = calibrate(nom, (q, compliant_fk(truth, q)[:, :3, 3]), priors={"excitation_mm": 0})
    assert res.position_only and "rot_mean_deg" not in res.after
    ident = dict(zip(res.names, res.identifiable))
    assert not ident["tool.rx"] and not ident["tool.ry"] and not ident["tool.rz"]
    n_geo = sum(m for n, m in zip(res.names, res.identifiable) if _kind(n) != "c")
    assert n_geo == 27  # 4R + 2P + 6 - 3 for position measurements
    qt = nom.random_joints(1000, rng)
    Tp, Tt = calibrated_fk(res.robot, qt), compliant_fk(truth, qt)
    assert np.linalg.norm(Tp[:, :3, 3] - Tt[:, :3, 3], axis=1).max() < 1e-6
    # the same data with orientations identify the tool orientation as well
    full = calibrate(nom, (q, compliant_fk(truth, q)), compliance=False, max_iter=1)
    assert all(dict(zip(full.names, full.identifiable))[f"tool.r{a}"] for a in "xyz")


def test_redundant_dh_parameters_detected():
    rng = np.random.default_rng(6)
    nom = _rx160()
    q = nom.random_joints(800, rng)
    T = compliant_fk(nom, q)
    res = calibrate(nom, (q, T), max_iter=1)
    ident = dict(zip(res.names, res.identifiable))
    # theta1, d1: same motion as base.rz, base.z; d3: same as d2 (axes 2, 3 parallel);
    # joint 6 fixed part: same as the tool frame; c1: vertical axis, no gravity torque
    for n in ("theta1", "d1", "d3", "a6", "alpha6", "d6", "theta6", "beta6", "c1"):
        assert not ident[n], n
    for n in ("a1", "alpha1", "a2", "alpha2", "d2", "theta2", "beta2", "a3", "theta4", "c2", "c6", "base.rz", "tool.z"):
        assert ident[n], n
    # without base and tool frames, joint 1 and joint 6 parameters carry that information
    rb = calibrate(nom, (q, T), base=False, tool=False, max_iter=1)
    idb = dict(zip(rb.names, rb.identifiable))
    assert idb["theta1"] and idb["d1"] and idb["d6"] and idb["theta6"]
    assert not any(n.startswith(("base.", "tool.")) for n in rb.names)


# --------------------------------------------------------------------------- statistics


def test_std_consistent_with_noise():
    """20 µm position noise (and 50 µrad orientation noise): ~95 % of errors within 2 sigma."""
    rng = np.random.default_rng(7)
    nom = _rx160().copy(stiffness_nm_per_rad=np.array([2e5, 1e5, 1e5, 5e4, 5e4, 2e4]))
    z_all = []
    for rep in range(2):
        q = nom.random_joints(1000, rng)
        probe = calibrate(nom, (q, compliant_fk(nom, q)), max_iter=1)
        truth, dev = _random_truth(nom, rng, probe.names, probe.identifiable)
        T = compliant_fk(truth, q)
        T[:, :3, 3] += rng.normal(0, 20e-6, (len(q), 3))
        T[:, :3, :3] = se3.rotvec_to_matrix(rng.normal(0, 50e-6, (len(q), 3))) @ T[:, :3, :3]
        res = calibrate(nom, (q, T))
        assert abs(res.sigma_pos_m / 20e-6 - 1) < 0.1
        assert abs(res.sigma_rot_rad / 50e-6 - 1) < 0.1
        for n, v in dev.items():
            k = res.names.index(n)
            if np.isfinite(res.std[k]):
                z_all.append((res.values[k] - v) / res.std[k])
    z = np.abs(np.array(z_all))
    assert len(z) > 60
    frac = np.mean(z < 2)
    assert 0.85 <= frac <= 1.0, frac
    assert 0.5 < np.mean(z**2) < 1.8


def test_correlations_and_report():
    rng = np.random.default_rng(8)
    nom = _rx160()
    truth, _ = _random_truth(nom, rng)
    q = nom.random_joints(600, rng)
    T = compliant_fk(truth, q)
    T[:, :3, 3] += rng.normal(0, 20e-6, (len(q), 3))
    res = calibrate(nom, (q, T[:, :3, 3]))
    k = len(res.correlation_names)
    assert res.correlation.shape == (k, k)
    np.testing.assert_allclose(np.diag(res.correlation), 1.0, atol=1e-9)
    np.testing.assert_allclose(res.correlation, res.correlation.T, atol=1e-12)
    for a, b, rho in res.strong_correlations:
        i, j = res.correlation_names.index(a), res.correlation_names.index(b)
        assert abs(res.correlation[i, j] - rho) < 1e-12 and abs(rho) > 0.9
    text = res.report()
    assert "base.x" in text and "held at prior" in text and "pos mean mm" in text
    d = json.loads(json.dumps(res.to_dict()))
    assert len(d["parameters"]) == len(res.names) and d["n_samples"] == 600
    # replaying the identified deviations on the input robot gives the calibrated robot
    replay = apply_deviations(nom, dict(zip(res.names, res.values)))
    np.testing.assert_allclose(calibrated_fk(replay, q), calibrated_fk(res.robot, q), atol=1e-12)


# --------------------------------------------------------------------------- Jacobian, inputs


@pytest.mark.parametrize("conv", ["dh", "mdh"])
def test_identification_jacobian_matches_finite_differences(conv):
    rng = np.random.default_rng(9)
    rigid = _rx160(stiff=False)
    # Compliant robot: the Jacobian leaves out how geometry moves the gravity torques (e.g. tool.x
    # moves the 20 kg payload: 196 N·m/m x 1e-5 rad/N·m) and the c·dtau/dq coupling, both ~1e-3 of
    # the column; the residual is exact, so only the convergence rate feels it.
    for robot, tol in ((rigid, 1e-7), (_rx160(), 1e-2)):
        robot = dh_to_mdh(robot) if conv == "mdh" else robot
        robot, _ = _random_truth(robot, rng)  # evaluate away from the nominal point
        q = robot.random_joints(20, rng)
        names, J = identification_jacobian(robot, q)
        T0 = compliant_fk(robot, q)
        for k, n in enumerate(names):
            h = 1e-6 * UNIT[_kind(n)] * 1e3
            Tp = compliant_fk(apply_deviations(robot, {n: h}), q)
            Tm = compliant_fk(apply_deviations(robot, {n: -h}), q) if _kind(n) != "c" or compliance_of(robot)[int(n[1:]) - 1] > h else T0
            hm = h if Tm is not T0 else 0.0
            dp = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (h + hm)
            dr = (se3.rotation_difference_rotvec(Tp[:, :3, :3], T0[:, :3, :3])
                  - se3.rotation_difference_rotvec(Tm[:, :3, :3], T0[:, :3, :3])) / (h + hm)
            fd = np.concatenate([dp, dr], 1)
            scale = max(np.abs(J[:, :, k]).max(), np.abs(fd).max(), 1e-12)
            # compliance columns: one-sided differences at c = 0 and the c·dtau/dq coupling that the
            # Jacobian leaves out (relative ~1e-3 for these stiffnesses) set the tolerance
            tk = max(tol, 1e-5) if _kind(n) == "c" else tol
            assert np.abs(J[:, :, k] - fd).max() < tk * scale + 1e-9, (conv, n)


def test_dataset_input_and_bad_input():
    from hykin.io.dataset import Dataset

    rng = np.random.default_rng(10)
    nom = _rx160()
    q = nom.random_joints(300, rng)
    T = compliant_fk(nom, q)
    res = calibrate(nom, Dataset.from_poses(q, T), compliance=False)
    assert res.after["pos_max_mm"] < 1e-9 and not res.position_only
    res_p = calibrate(nom, Dataset.from_poses(q, T, orientation=False), compliance=False, max_iter=2)
    assert res_p.position_only
    with pytest.raises(CalibrationError, match="joints must be"):
        calibrate(nom, (q[:, :5], T))
    bad = T.copy()
    bad[7, 0, 3] = np.nan
    with pytest.raises(CalibrationError, match="row 8"):
        calibrate(nom, (q, bad))
    with pytest.raises(CalibrationError, match="matches no parameter"):
        calibrate(nom, (q, T), params=["nope*"])
    with pytest.raises(CalibrationError, match="orientation_weight"):
        calibrate(nom, (q, T), orientation_weight_m_per_rad=0.0)
    with pytest.raises(CalibrationError, match="no orientations"):
        calibrate(nom, (q, T[:, :3, 3]), position_only=False)
    with pytest.raises(CalibrationError, match="unknown parameter"):
        apply_deviations(nom, {"zz9": 1.0})


def test_coarse_to_fine_gives_the_same_solution(monkeypatch):
    """Large data sets first converge on a spread subset; the end point is that of all samples."""
    import importlib

    cal = importlib.import_module("hykin.calibration.calibrate")  # the module (hykin.calibrate is the function)

    rng = np.random.default_rng(14)
    nom = _rx160()
    truth, _ = _random_truth(nom, rng)
    q = nom.random_joints(900, rng)
    T = compliant_fk(truth, q)
    T[:, :3, 3] += rng.normal(0, 20e-6, (len(q), 3))
    plain = calibrate(nom, (q, T))
    monkeypatch.setattr(cal, "_COARSE_SAMPLES", 300)
    coarse = calibrate(nom, (q, T))
    np.testing.assert_array_equal(coarse.identifiable, plain.identifiable)
    k = plain.identifiable & np.isfinite(plain.std)
    assert k.sum() > 30 and np.all(np.abs(coarse.values[k] - plain.values[k]) < 1e-3 * plain.std[k])
    assert abs(coarse.after["pos_rms_mm"] / plain.after["pos_rms_mm"] - 1) < 1e-6


def test_register_base_and_tool_only():
    """A moved tracker and a new tool: re-fit base and tool only (``params=["base.*", "tool.*"]``)."""
    rng = np.random.default_rng(11)
    robot = _rx160()
    moved = apply_deviations(robot, {"base.x": 0.3, "base.rz": 0.5, "base.ry": -0.02, "tool.z": 0.04, "tool.rx": 0.1})
    q = robot.random_joints(200, rng)
    res = calibrate(robot, (q, compliant_fk(moved, q)), params=["base.*", "tool.*"])
    assert res.names == parameter_names(robot)[:12]
    np.testing.assert_allclose(res.robot.base, moved.base, atol=1e-12)
    np.testing.assert_allclose(res.robot.tool, moved.tool, atol=1e-12)
    assert math.isclose(res.value("base.rz"), 0.5, abs_tol=1e-12)


# --------------------------------------------------------------------------- virtual presets, real data


def test_virtual_preset_rx160_geometric():
    simulate = pytest.importorskip("hykin.sim.simulate")
    vr = pytest.importorskip("hykin.sim.presets").virtual_preset("rx160-geometric")
    rng = np.random.default_rng(12)
    q = vr.nominal.random_joints(1200, rng)
    res = calibrate(vr.nominal, simulate.simulate(vr, q, noise=False))
    qt = vr.nominal.random_joints(1000, rng)
    pe, ae = _pose_err(calibrated_fk(res.robot, qt), simulate.true_poses(vr, qt))
    # The preset's 10 kg gripper sits in the flange frame, whose deviation is kinematically
    # unidentifiable (it is merged into the tool): its gravity torque is off by ~0.03 N·m on the
    # soft wrist, a floor of ~0.3 µm / 5e-5 deg. Everything else is exact.
    assert pe.max() < 1e-3 and ae.max() < 2e-4
    np.testing.assert_allclose(compliance_of(res.robot)[1:], compliance_of(vr.truth)[1:], rtol=1e-2)


def _load_ur5(name):
    a = np.genfromtxt(UR5_DIR / name, delimiter=",", names=True)
    q = np.radians(np.stack([a[f"joint_{i}"] for i in range(1, 7)], 1))
    p = np.stack([a["x_t"] + a["x_dif"], a["y_t"] + a["y_dif"], a["z_t"] + a["z_dif"]], 1) * 1e-3
    return q, p


@pytest.mark.skipif(not UR5_DIR.is_dir(), reason=f"real UR5 data not found at {UR5_DIR} (set HYKIN_SHARED_DATA)")
def test_real_ur5_geometric_calibration():
    """UR5 laser-tracker data: train on the 1000-pose grid, test on the 20 random poses.

    Measured: 2.562 mm mean uncalibrated -> 0.1005 mm (geometry) / 0.098 mm (with compliance).
    """
    qtr, ptr = _load_ur5("3D_UR5_uncalibrated_grid_cleaned.csv")
    qte, pte = _load_ur5("3D_UR5_uncalibrated_random_cleaned.csv")
    ur5 = load_robot("ur5").copy(tool=se3.trans(0.0, 0.0, 0.031))
    before = np.linalg.norm(calibrated_fk(ur5, qte)[:, :3, 3] - pte, axis=1).mean() * 1e3
    assert 2.4 < before < 2.7
    for comp in (False, True):
        res = calibrate(ur5, (qtr, ptr), compliance=comp)
        after = np.linalg.norm(calibrated_fk(res.robot, qte)[:, :3, 3] - pte, axis=1).mean() * 1e3
        assert after < 0.12, (comp, after)
