"""hykin.measure (fits, referencing, rigid): fits recover known geometry; stated uncertainties match Monte-Carlo scatter."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hykin.geometry import se3
from hykin.geometry.lsq import ReferencingError
from hykin.geometry.rigid import kabsch, pose_from_three_points, register_points
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk_frames
from hykin.measure.fits import axis_from_sweep, fit_circle_3d, fit_plane
from hykin.measure.referencing import base_frame_from_sweeps, tool_frame_from_sweeps

NOISE = 15e-6  # tracker-like, m


def _circle(center, normal, radius, angles):
    n = normal / np.linalg.norm(normal)
    a = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return center + radius * (np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v)


def _angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)


# --------------------------------------------------------------------------- plane / circle


def test_plane_noise_free_and_degenerate():
    rng = np.random.default_rng(0)
    n = np.array([0.3, -0.5, 0.8])
    n /= np.linalg.norm(n)
    pts = _circle(np.array([1.0, 2.0, 0.5]), n, 1.0, rng.uniform(0, 6, 20)) * 1.0
    pts += (rng.uniform(-0.3, 0.3, (20, 1))) * np.cross(n, [0, 0, 1]) / np.linalg.norm(np.cross(n, [0, 0, 1]))
    pl = fit_plane(pts)
    assert _angle(pl.normal, n) < 1e-12 and pl.normal[np.argmax(np.abs(pl.normal))] > 0
    assert abs((pl.point - [1, 2, 0.5]) @ n) < 1e-12 and pl.rms_m < 1e-12
    with pytest.raises(ReferencingError, match="collinear"):
        fit_plane(np.outer(np.linspace(0, 1, 5), [1, 2, 3]))
    with pytest.raises(ReferencingError, match="at least 3"):
        fit_plane(np.zeros((2, 3)))
    with pytest.raises(ReferencingError, match="non-finite"):
        fit_plane(np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan]]))


def test_plane_uncertainty_monte_carlo():
    rng = np.random.default_rng(1)
    n = np.array([0.0, 0.6, 0.8])
    base = np.c_[rng.uniform(-0.5, 0.5, (15, 2)), np.zeros(15)]
    R = Rotation.align_vectors([n], [[0, 0, 1]])[0].as_matrix()
    base = base @ R.T
    z = []
    for _ in range(200):
        pl = fit_plane(base + rng.normal(0, NOISE, base.shape))
        z.append(_angle(pl.normal, n) / pl.normal_std_rad)
    rms = np.sqrt(np.mean(np.square(z)))
    assert 0.7 < rms < 1.4, rms


def test_circle_noise_free_partial_arc():
    c, n, r = np.array([0.4, -1.2, 0.9]), np.array([0.2, 0.1, -1.0]), 0.731
    n = n / np.linalg.norm(n)
    pts = _circle(c, n, r, np.linspace(-0.4, 0.5, 12))  # ~52 degrees of arc
    f = fit_circle_3d(pts)
    assert _angle(f.normal, n) < 1e-9  # traversal order gives the sign
    assert np.linalg.norm(f.center - c) < 1e-9 and abs(f.radius_m - r) < 1e-9
    f2 = fit_circle_3d(pts[::-1])
    assert _angle(f2.normal, -n) < 1e-9
    with pytest.raises(ReferencingError, match="at least 4"):
        fit_circle_3d(pts[:3])
    with pytest.raises(ReferencingError):
        fit_circle_3d(np.outer(np.linspace(0, 1, 6), [1, 0, 0]))


def test_axis_uncertainty_monte_carlo():
    """200 noisy sweeps (90 deg arc, 25 points, 15 um): |error| / stated std has RMS ~ 1."""
    rng = np.random.default_rng(2)
    c, n, r = np.array([1.0, 0.5, 0.3]), np.array([0.1, -0.2, 1.0]), 0.8
    n = n / np.linalg.norm(n)
    clean = _circle(c, n, r, np.linspace(0, np.pi / 2, 25))
    zd, zp, zc, zr, cover = [], [], [], [], []
    P = np.eye(3) - np.outer(n, n)
    for _ in range(200):
        ax = axis_from_sweep(clean + rng.normal(0, NOISE, clean.shape))
        e_dir = _angle(ax.direction, n)
        e_pt = np.linalg.norm(P @ (ax.point - c))
        zd.append(e_dir / ax.std_dir_rad)
        zp.append(e_pt / ax.std_point_m)
        zc.append(np.linalg.norm(ax.point - c) / ax.circle.center_std_m)
        zr.append((ax.radius_m - r) / ax.circle.radius_std_m)
        # 95 % coverage of the 2-D tilt: chi2(2) quantile 5.991
        u, v = ax.circle.basis
        t = np.array([(n - ax.direction) @ u, (n - ax.direction) @ v])
        cover.append(t @ np.linalg.solve(ax.circle.cov[3:5, 3:5], t) < 5.991)
    for name, z in (("dir", zd), ("point", zp), ("centre", zc), ("radius", zr)):
        rms = np.sqrt(np.mean(np.square(z)))
        assert 0.7 < rms < 1.4, (name, rms)
    assert 0.88 <= np.mean(cover) <= 0.99, np.mean(cover)
    assert 0.5 * NOISE < ax.rms_m < 1.5 * NOISE


# --------------------------------------------------------------------------- frames from robot sweeps


def _sweeps(robot, q0, smr, joints, span=0.6, n=25, noise=0.0, rng=None):
    out = []
    for j in joints:
        Q = np.tile(q0, (n, 1))
        Q[:, j] = q0[j] + np.linspace(-span, span, n)
        F = fk_frames(robot, Q).link[:, -1]
        p = F[:, :3, :3] @ smr + F[:, :3, 3]
        out.append(p + (rng.normal(0, noise, p.shape) if noise else 0.0))
    return out


BASE = se3.xyzrpy_to_transform([2.0, -1.0, 0.3], [0.1, -0.2, 1.0])  # tracker -> robot base
Q0 = np.array([0.3, -0.4, 0.5, 0.2, 0.6, 0.1])
SMR = np.array([0.05, 0.03, 0.12])


@pytest.mark.parametrize("name", ["rx160", "ur5", "kuka-kr6-r900"])
def test_frames_noise_free(name):
    """rx160/kr6: offset axes 1-2 (common perpendicular); ur5: intersecting axes (DH twist rule)."""
    robot = load_robot(name).copy(base=BASE)
    j1, j2, j5, j6 = _sweeps(robot, Q0, SMR, [0, 1, 4, 5])
    fb = base_frame_from_sweeps(j1, j2, robot=robot, q1_rad=Q0[0])
    assert np.linalg.norm(fb.T[:3, 3] - BASE[:3, 3]) < 1e-9
    assert np.linalg.norm(se3.matrix_to_rotvec(fb.T[:3, :3] @ BASE[:3, :3].T)) < 1e-9
    ft = tool_frame_from_sweeps(j5, j6, robot=robot, q6_rad=Q0[5])
    F = fk_frames(robot, Q0[None]).link[0, -1]
    assert np.linalg.norm(ft.T[:3, 3] - F[:3, 3]) < 1e-9
    assert np.linalg.norm(se3.matrix_to_rotvec(ft.T[:3, :3] @ F[:3, :3].T)) < 1e-9
    # SMR in flange coordinates
    p = j6[12]
    np.testing.assert_allclose(np.linalg.solve(ft.T, np.r_[p, 1])[:3], SMR, atol=1e-9)


def test_base_frame_with_plane_points_and_errors():
    robot = load_robot("rx160").copy(base=BASE)
    j1, j2 = _sweeps(robot, Q0, SMR, [0, 1])
    rng = np.random.default_rng(3)
    floor = np.c_[rng.uniform(-0.5, 0.5, (10, 2)), np.zeros(10)] + [0, 0, 0.0]
    floor_tracker = floor @ BASE[:3, :3].T + BASE[:3, 3]
    # base plane measured on the floor: same frame, d1 ignored
    fb = base_frame_from_sweeps(j1, j2, robot=robot, q1_rad=Q0[0], base_plane_points=floor_tracker)
    assert np.linalg.norm(fb.T[:3, 3] - BASE[:3, 3]) < 1e-9
    ur = load_robot("ur5").copy(base=BASE)
    u1, u2 = _sweeps(ur, Q0, SMR, [0, 1])
    with pytest.raises(ReferencingError, match="alpha_rad"):
        base_frame_from_sweeps(u1, u2, q1_rad=Q0[0])  # intersecting axes and no twist given
    with pytest.raises(ReferencingError, match="parallel"):
        base_frame_from_sweeps(j1, j1 + [0.1, 0, 0])


def test_frame_uncertainty_monte_carlo():
    robot = load_robot("rx160").copy(base=BASE)
    rng = np.random.default_rng(4)
    zp, zr = [], []
    for _ in range(100):
        j1, j2 = _sweeps(robot, Q0, SMR, [0, 1], noise=NOISE, rng=rng)
        fb = base_frame_from_sweeps(j1, j2, robot=robot, q1_rad=Q0[0])
        zp.append(np.linalg.norm(fb.T[:3, 3] - BASE[:3, 3]) / fb.pos_std_m)
        zr.append(np.linalg.norm(se3.matrix_to_rotvec(fb.T[:3, :3] @ BASE[:3, :3].T)) / fb.rot_std_rad)
    for name, z in (("pos", zp), ("rot", zr)):
        rms = np.sqrt(np.mean(np.square(z)))
        assert 0.7 < rms < 1.4, (name, rms)


# --------------------------------------------------------------------------- registration


def test_kabsch_known_transform_scale_weights():
    rng = np.random.default_rng(5)
    P = rng.normal(size=(30, 3))
    R = Rotation.random(random_state=5).as_matrix()
    t = np.array([0.3, -2.0, 1.0])
    Q = 1.7 * P @ R.T + t
    R1, t1, s1 = kabsch(P, Q, scale=True)
    np.testing.assert_allclose(R1, R, atol=1e-12)
    np.testing.assert_allclose(t1, t, atol=1e-12)
    assert s1 == pytest.approx(1.7, abs=1e-12)
    # rigid, with outliers given zero weight
    Q2 = P @ R.T + t
    Q2[:5] += rng.normal(0, 0.5, (5, 3))
    w = np.r_[np.zeros(5), np.ones(25)]
    R2, t2 = kabsch(P, Q2, weights=w)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)
    # weighted rotation against scipy's align_vectors (independent implementation)
    Q3 = Q2 + rng.normal(0, 0.01, Q2.shape)
    w3 = rng.uniform(0.1, 2.0, 30)
    R3, t3 = kabsch(P, Q3, weights=w3)
    mp = (w3[:, None] * P).sum(0) / w3.sum()
    mq = (w3[:, None] * Q3).sum(0) / w3.sum()
    ref = Rotation.align_vectors(Q3 - mq, P - mp, weights=w3)[0].as_matrix()
    np.testing.assert_allclose(R3, ref, atol=1e-10)
    np.testing.assert_allclose(t3, mq - R3 @ mp, atol=1e-12)
    # integer weights == duplicated points
    wi = rng.integers(1, 4, 30)
    Ra, ta = kabsch(P, Q3, weights=wi)
    Rb, tb = kabsch(np.repeat(P, wi, 0), np.repeat(Q3, wi, 0))
    np.testing.assert_allclose(Ra, Rb, atol=1e-12)
    np.testing.assert_allclose(ta, tb, atol=1e-12)


def test_kabsch_reflection_and_degenerate():
    rng = np.random.default_rng(6)
    P = rng.normal(size=(10, 3))
    Q = P * [1, 1, -1]  # a mirror image: the best orthogonal map is a reflection
    R, t = kabsch(P, Q)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # must equal the best proper rotation (scipy's align_vectors is constrained to rotations)
    mp, mq = P.mean(0), Q.mean(0)
    ref = Rotation.align_vectors(Q - mq, P - mp)[0].as_matrix()
    np.testing.assert_allclose(R, ref, atol=1e-9)
    with pytest.raises(ReferencingError, match="collinear"):
        kabsch(np.outer(np.arange(4.0), [1, 1, 0]), rng.normal(size=(4, 3)))
    with pytest.raises(ReferencingError, match="at least 3"):
        kabsch(P[:2], Q[:2])
    with pytest.raises(ReferencingError, match="shape"):
        kabsch(P, Q[:5])


def test_register_points_uncertainty_monte_carlo():
    rng = np.random.default_rng(7)
    P = rng.uniform(-1, 1, (12, 3))
    R = Rotation.random(random_state=7).as_matrix()
    t = np.array([1.0, 2.0, -0.5])
    zt, zr = [], []
    for _ in range(200):
        reg = register_points(P, P @ R.T + t + rng.normal(0, NOISE, P.shape))
        et = reg.T[:3, 3] - t
        er = se3.matrix_to_rotvec(R @ reg.T[:3, :3].T)  # R_true = exp(er) R_est
        zt.append(et @ np.linalg.solve(reg.cov[:3, :3], et))
        zr.append(er @ np.linalg.solve(reg.cov[3:6, 3:6], er))
    # Mahalanobis^2 of a 3-D Gaussian has mean 3
    assert 0.7 * 3 < np.mean(zt) < 1.4 * 3
    assert 0.7 * 3 < np.mean(zr) < 1.4 * 3
    assert reg.residuals_m.shape == P.shape and 0.5 * NOISE < reg.rms_m / np.sqrt(3) < 1.5 * NOISE
    np.testing.assert_allclose(reg.apply(P), P @ reg.T[:3, :3].T + reg.T[:3, 3])


def test_pose_from_three_points():
    rng = np.random.default_rng(8)
    nest = np.array([[0.05, 0.0, 0.0], [-0.03, 0.04, 0.01], [-0.02, -0.05, 0.02]])
    N = 64
    T = se3.make_transform(Rotation.random(N, random_state=8).as_matrix(), rng.uniform(-2, 2, (N, 3)))
    meas = np.einsum("nij,kj->nki", T[:, :3, :3], nest) + T[:, None, :3, 3]
    Te, res = pose_from_three_points(meas[:, 0], meas[:, 1], meas[:, 2], nest, return_residual=True)
    np.testing.assert_allclose(Te, T, atol=1e-12)
    assert res.max() < 1e-12
    # agrees with the single-set kabsch under noise
    noisy = meas + rng.normal(0, NOISE, meas.shape)
    Tn = pose_from_three_points(noisy[:, 0], noisy[:, 1], noisy[:, 2], nest)
    R5, t5 = kabsch(nest, noisy[5])
    np.testing.assert_allclose(Tn[5, :3, :3], R5, atol=1e-12)
    np.testing.assert_allclose(Tn[5, :3, 3], t5, atol=1e-12)
    bad = meas.copy()
    bad[3] = [[0, 0, 0], [1, 1, 1], [2, 2, 2]]
    with pytest.raises(ReferencingError, match=r"row\(s\) \[3\]"):
        pose_from_three_points(bad[:, 0], bad[:, 1], bad[:, 2], nest)
    with pytest.raises(ReferencingError, match="nest"):
        pose_from_three_points(meas[:, 0], meas[:, 1], meas[:, 2], [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
