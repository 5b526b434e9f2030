"""Virtual robots (hykin.simulate) and sampling plans (hykin.sampling)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import qmc

from hykin.geometry.se3 import pose_error, pose_to_transform
from hykin.io.dataset_files import read_dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.compliance import deflected_joints
from hykin.kinematics.fk import fk
from hykin.sim.generate import simulate_to_file
from hykin.sim.presets import list_virtual_presets, virtual_preset
from hykin.sim.sampling import PlanError, iso_cube, restricted, sample, uniform, zigzag
from hykin.sim.simulate import (
    PeriodicError,
    SimulationError,
    ThermalDrift,
    VirtualRobot,
    dataset_error,
    load_truth,
    save_truth,
    simulate,
    true_poses,
)

# ---------------------------------------------------------------- simulator


def _plain(noise_pos=0.0, noise_ang=0.0, **kw):
    r = load_robot("rx160")
    return VirtualRobot("plain", nominal=r, truth=r.copy(), noise_position_m=noise_pos, noise_orientation_rad=noise_ang, **kw)


def test_no_errors_gives_nominal_pose_exactly():
    vr = _plain()
    q = vr.nominal.random_joints(200, 0)
    ds = simulate(vr, q)
    T = fk(vr.nominal, q)
    np.testing.assert_allclose(ds.xyz_m, T[:, :3, 3], rtol=0, atol=1e-15)
    pos, ang = pose_error(ds.poses(), T)
    assert pos.max() < 1e-12 and ang.max() < 1e-6  # quaternion round trip only
    np.testing.assert_array_equal(true_poses(vr, q), T)


def test_true_pose_is_deflected_truth_fk():
    vr = virtual_preset("rx160-geometric", seed=3)
    q = vr.nominal.random_joints(100, 1)
    T = true_poses(vr, q)
    np.testing.assert_array_equal(T, fk(vr.truth, deflected_joints(vr.truth, q)))
    assert not np.allclose(T, fk(vr.nominal, q), atol=1e-4)


def test_reproducible_from_seed():
    vr = virtual_preset("rx160-nongeo", seed=1)
    q = vr.nominal.random_joints(300, 2)
    a, b = simulate(vr, q, rng=5), simulate(vr, q, rng=5)
    np.testing.assert_array_equal(a.xyz_m, b.xyz_m)
    np.testing.assert_array_equal(a.quat_wxyz, b.quat_wxyz)
    c = simulate(vr, q, rng=6)
    assert not np.array_equal(a.xyz_m, c.xyz_m)
    # the preset itself is reproducible from its seed, and seeds differ
    v1, v2 = virtual_preset("ur10-virtual", seed=4), virtual_preset("ur10-virtual", seed=4)
    np.testing.assert_array_equal(v1.truth.a_m, v2.truth.a_m)
    assert not np.array_equal(v1.truth.a_m, virtual_preset("ur10-virtual", seed=5).truth.a_m)


def test_noise_statistics():
    sp, sr = 20e-6, 1e-4
    vr = _plain(sp, sr)
    q = vr.nominal.random_joints(20_000, 7)
    ds = simulate(vr, q, rng=11)
    T = fk(vr.nominal, q)
    dp = ds.xyz_m - T[:, :3, 3]
    np.testing.assert_allclose(dp.std(axis=0), sp, rtol=0.1)
    assert np.abs(dp.mean(axis=0)).max() < 0.1 * sp
    dr = (Rotation.from_matrix(ds.rotations()) * Rotation.from_matrix(T[:, :3, :3]).inv()).as_rotvec()
    np.testing.assert_allclose(dr.std(axis=0), sr, rtol=0.1)
    # noise=False switches it off
    np.testing.assert_allclose(simulate(vr, q[:50], noise=False).xyz_m, T[:50, :3, 3], atol=1e-15)


# Figures stated in the hykin.sim.presets docstring (seed 0), mean over uniform samples.
EXPECTED = {
    "rx160-virtual": (1.80, 0.170, 0.20, 0.25),  # paper Table I, tolerance ±20 % / ±25 %
    "rx160-geometric": (2.98, 0.205, 0.25, 0.25),
    "rx160-nongeo": (2.99, 0.204, 0.25, 0.25),
    "ur10-virtual": (4.95, 0.479, 0.25, 0.25),
    "kr-payload-virtual": (5.43, 0.199, 0.25, 0.25),  # no payload column: the preset's payload (0 kg)
}


@pytest.mark.parametrize("name", list_virtual_presets())
def test_preset_dataset_errors(name):
    vr = virtual_preset(name, seed=0)
    q = sample("random", vr.nominal, 2000, 123)
    pos, ang = dataset_error(vr, q)
    mm, deg, tp, ta = EXPECTED[name]
    assert pos == pytest.approx(mm, rel=tp)
    assert ang == pytest.approx(deg, rel=ta)
    # the nominal model is rigid and has the classical geometry of its preset
    assert not vr.nominal.has_compliance
    base = load_robot("kr-payload" if name == "kr-payload-virtual" else name.split("-")[0])
    np.testing.assert_array_equal(fk(vr.nominal, q[:10]), fk(base, q[:10]))


def test_rx160_virtual_is_compliance_only():
    vr = virtual_preset("rx160-virtual")
    for k in ("a_m", "alpha_rad", "d_m", "theta_rad", "beta_rad", "base", "tool"):
        np.testing.assert_array_equal(getattr(vr.truth, k), getattr(vr.nominal, k))
    assert vr.noise_position_m == 0 and not vr.transmission and vr.thermal is None
    assert vr.truth.payload_kg == 20.0


def test_transmission_error():
    vr = _plain()
    vr.transmission = [PeriodicError(joint=2, amplitude_rad=3e-4, order=2.0, gear_ratio=1.0, phase_rad=0.4),
                       PeriodicError(joint=5, amplitude_rad=1e-4, order=1.0, gear_ratio=30.0, phase_rad=0.0)]
    q = vr.nominal.random_joints(100, 3)
    q_link = q.copy()
    q_link[:, 1] += 3e-4 * np.sin(2 * q[:, 1] + 0.4)
    q_link[:, 4] += 1e-4 * np.sin(30 * q[:, 4])
    np.testing.assert_allclose(true_poses(vr, q), fk(vr.nominal, q_link), rtol=0, atol=1e-15)


def test_thermal_drift_scales_base_frame_position():
    r = load_robot("rx160")
    from hykin.geometry.se3 import make_transform, rotvec_to_matrix

    base = make_transform(rotvec_to_matrix(np.array([0.1, -0.2, 0.3])), np.array([0.5, -0.2, 0.1]))
    r = r.copy(base=base)
    th = ThermalDrift(coefficient_per_k=2e-5, reference_c=20.0, start_c=20.0, end_c=30.0, time_constant_samples=50)
    vr = VirtualRobot("thermal", nominal=r, truth=r.copy(), thermal=th)
    q = r.random_joints(400, 4)
    ds = simulate(vr, q)
    temp = ds.extra["temperature_c"]
    np.testing.assert_allclose(temp, 20.0 + 10.0 * (1 - np.exp(-np.arange(400) / 50.0)), rtol=0, atol=1e-12)
    T = fk(r, q)
    p_base = (np.linalg.inv(base)[None] @ T)[:, :3, 3]
    p_sim = (np.linalg.inv(base)[None] @ ds.poses())[:, :3, 3]
    np.testing.assert_allclose(p_sim, p_base * (1 + 2e-5 * (temp - 20.0))[:, None], rtol=0, atol=1e-14)
    # explicit temperature, and the same result as link lengths scaled in the model (rigid chain)
    t_fixed = np.full(len(q), 45.0)
    s = 1 + 2e-5 * 25.0
    scaled = r.copy(a_m=r.a_m * s, d_m=r.d_m * s)
    T_scaled = fk(scaled, q)
    np.testing.assert_allclose(simulate(vr, q, temperature=t_fixed).xyz_m, T_scaled[:, :3, 3], rtol=0, atol=1e-14)


def test_truth_file_round_trip(tmp_path):
    vr = virtual_preset("rx160-nongeo", seed=2)
    path = save_truth(vr, tmp_path / "t.truth.json")
    text = path.read_text()
    assert '"stiffness_nm_per_rad"' in text and "null" in text  # human-readable, rigid = null
    back = load_truth(path)
    q = vr.nominal.random_joints(50, 0)
    np.testing.assert_array_equal(true_poses(back, q), true_poses(vr, q))
    np.testing.assert_array_equal(simulate(back, q, rng=1).xyz_m, simulate(vr, q, rng=1).xyz_m)
    assert back.transmission == vr.transmission and back.thermal == vr.thermal
    assert not back.nominal.has_compliance
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "something-else"}')
    with pytest.raises(SimulationError, match="bad.json"):
        load_truth(bad)


def test_simulate_to_file(tmp_path):
    calls = []
    out = tmp_path / "data.csv"
    truth = simulate_to_file("rx160-nongeo", 1200, out, plan="zigzag", seed=3, chunk=500,
                             progress=lambda d, t: calls.append((d, t)))
    assert calls == [(500, 1200), (1000, 1200), (1200, 1200)]
    assert truth.endswith("data.truth.json")
    ds = read_dataset(out)
    vr = load_truth(truth)
    assert len(ds) == 1200 and ds.has_orientation and "temperature_c" in ds.extra
    pos, _ = pose_error(pose_to_transform(ds.xyz_m, ds.quat_wxyz), true_poses(vr, ds.q))
    assert 1e-4 < pos.mean() < 0.1  # noise of 10 µm per axis -> mean norm ≈ 16 µm
    # same arguments, same file
    simulate_to_file("rx160-nongeo", 1200, tmp_path / "again.csv", plan="zigzag", seed=3)
    assert (tmp_path / "again.csv").read_text() == out.read_text()
    truth = simulate_to_file("rx160-virtual", 12, tmp_path / "iso.csv", plan="iso-cube", seed=0, noise=False)
    iso = read_dataset(tmp_path / "iso.csv")
    np.testing.assert_array_equal(iso.extra["pose"], np.tile(np.arange(1, 6), 3)[:12].astype(str))  # labels as written
    with pytest.raises(SimulationError):
        simulate_to_file("no-such-robot", 10, tmp_path / "x.csv")


def test_bad_input():
    vr = _plain()
    with pytest.raises(SimulationError):
        simulate(vr, np.zeros((4, 5)))
    q = np.zeros((4, 6))
    q[2, 3] = np.nan
    with pytest.raises(SimulationError, match="row 2, column q4"):
        simulate(vr, q)
    with pytest.raises(SimulationError):
        virtual_preset("nope")


# ---------------------------------------------------------------- sampling plans


@pytest.mark.parametrize("name", ["rx160", "ur10"])
@pytest.mark.parametrize("plan", ["uniform", "random", "zigzag", "restricted", "iso-cube"])
def test_plans_within_limits(name, plan):
    r = load_robot(name)
    q = sample(plan, r, 700, 0)
    assert q.shape == (700, 6) and q.dtype == np.float64
    assert r.within_limits(q, tol=0).all()
    np.testing.assert_array_equal(q, sample(plan, r, 700, 0))  # reproducible


def test_uniform_is_low_discrepancy():
    r = load_robot("rx160")
    q = uniform(r, 1024, 1)
    u = (q - r.lower) / (r.upper - r.lower)
    v = (sample("random", r, 1024, 1) - r.lower) / (r.upper - r.lower)
    assert qmc.discrepancy(u) < 0.5 * qmc.discrepancy(v)
    # the full range is covered in every joint
    assert np.all(u.min(0) < 0.01) and np.all(u.max(0) > 0.99)


def test_zigzag_continuity_and_coverage():
    r = load_robot("rx160")
    n = 20_000
    q = zigzag(r, n, 2, sweeps=4)
    span = r.upper - r.lower
    rates = 4 * np.sqrt([2, 3, 5, 7, 11, 13]) / np.sqrt(2)
    steps = np.abs(np.diff(q, axis=0))
    bound = 2 * rates * span / (n - 1)  # triangle wave: |slope| = 2 * span per cycle
    assert np.all(steps <= bound * (1 + 1e-9))
    # each joint reaches both ends of its range (back and forth)
    u = (q - r.lower) / span
    assert np.all(u.min(0) < 0.01) and np.all(u.max(0) > 0.99)
    # direction reverses at least 2 * sweeps * rate times per joint
    turns = np.sum(np.diff(np.sign(np.diff(q, axis=0)), axis=0) != 0, axis=0)
    assert np.all(turns >= np.floor(2 * rates) - 1)


def test_restricted_ranges():
    r = load_robot("rx160")
    q = restricted(r, 500, 0, fraction=0.3)
    mid, half = 0.5 * (r.lower + r.upper), 0.15 * (r.upper - r.lower)
    assert np.all(q >= mid - half - 1e-12) and np.all(q <= mid + half + 1e-12)
    ranges = np.column_stack([r.lower * 0.1, r.upper * 0.2])
    q = restricted(r, 500, 0, ranges=ranges, method="random")
    assert np.all(q >= ranges[:, 0]) and np.all(q <= ranges[:, 1])
    with pytest.raises(PlanError, match="joint 1"):
        restricted(r, 10, 0, ranges=np.column_stack([r.lower * 2, r.upper]))
    with pytest.raises(PlanError):
        sample("spiral", r, 10, 0)
    with pytest.raises(PlanError):
        sample("uniform", r, 0, 0)


@pytest.mark.parametrize("name", ["rx160", "ur10"])
def test_iso_cube_poses(name):
    r = load_robot(name)
    plan = iso_cube(r, cycles=3, rng=0)
    assert plan.q.shape == (15, 6) and list(plan.labels[:6]) == [1, 2, 3, 4, 5, 1]
    T = fk(r, plan.q[:5])
    p = T[:, :3, 3]
    c, hs = plan.center_m, plan.side_m / 2
    np.testing.assert_allclose(p, plan.points_m, atol=1e-9)
    np.testing.assert_allclose(p[0], c, atol=1e-9)  # P1 at the centre
    # all on the diagonal plane through two opposite vertical edges: normal (1, -1, 0)/sqrt 2
    np.testing.assert_allclose((p - c) @ np.array([1.0, -1.0, 0.0]) / np.sqrt(2), 0.0, atol=1e-9)
    # P2..P5 on the space diagonals, 10 % of the diagonal length from a cube corner
    diag = np.sqrt(3) * plan.side_m
    for pk in p[1:]:
        d = pk - c
        assert np.linalg.norm(d) == pytest.approx(0.4 * diag, rel=1e-9)
        assert np.allclose(np.abs(d), 0.8 * hs, atol=1e-9)  # along a (±1, ±1, ±1) direction
    # constant orientation, all poses repeated identically per cycle
    _, ang = pose_error(T, np.broadcast_to(T[0], T.shape))
    assert ang.max() < 1e-6
    np.testing.assert_array_equal(plan.q[5:10], plan.q[:5])
    # one IK branch: neighbouring poses are close in joint space
    assert np.abs(plan.q[:5] - plan.q[0]).max() < 1.0
