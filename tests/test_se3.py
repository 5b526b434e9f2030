"""Property tests for hykin.se3: conversions round-trip, group laws, error metrics, torch twins."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from hykin.geometry import se3

torch = pytest.importorskip("torch")

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
vec3 = arrays(np.float64, 3, elements=finite)
# rotation vectors with angle in (0, pi - 1e-6): the log is unique there
rotvecs = arrays(np.float64, 3, elements=st.floats(-1, 1)).filter(lambda v: 1e-6 < np.linalg.norm(v)).map(
    lambda v: v / np.linalg.norm(v)
)
angles = st.floats(1e-9, math.pi - 1e-6)
quats = arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(lambda q: np.linalg.norm(q) > 1e-3)
SETTINGS = settings(max_examples=150, deadline=None)


def _rot(axis, angle):
    return se3.rotvec_to_matrix(axis * angle)


def _random_T(rng, n):
    return se3.make_transform(Rotation.random(n, random_state=rng).as_matrix(), rng.normal(size=(n, 3)))


@SETTINGS
@given(axis=rotvecs, angle=angles)
def test_rotvec_matrix_round_trip(axis, angle):
    R = _rot(axis, angle)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(se3.matrix_to_rotvec(R), axis * angle, atol=1e-9)
    # Rodrigues closed form
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    np.testing.assert_allclose(R, np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K, atol=1e-14)


@SETTINGS
@given(q=quats)
def test_quat_matrix_round_trip(q):
    q = q / np.linalg.norm(q)
    R = se3.quat_to_matrix(q)
    q2 = se3.matrix_to_quat(R)
    assert q2[0] >= 0
    # q and -q are the same rotation; the canonical one has qw >= 0
    d = min(np.abs(q2 - q).max(), np.abs(q2 + q).max())
    assert d < 1e-12
    if q[0] > 1e-9:
        np.testing.assert_allclose(q2, q, atol=1e-12)
    np.testing.assert_allclose(se3.quat_to_matrix(q2), R, atol=1e-14)
    # scalar-first closed form
    w, x, y, z = q
    Rref = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
    np.testing.assert_allclose(R, Rref, atol=1e-14)


@SETTINGS
@given(r=st.floats(-math.pi, math.pi), p=st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3), y=st.floats(-math.pi, math.pi))
def test_rpy_is_urdf_fixed_xyz(r, p, y):
    R = se3.rpy_to_matrix(np.array([r, p, y]))
    np.testing.assert_allclose(R, se3.rotz(y)[:3, :3] @ se3.roty(p)[:3, :3] @ se3.rotx(r)[:3, :3], atol=1e-14)
    np.testing.assert_allclose(se3.rpy_to_matrix(se3.matrix_to_rpy(R)), R, atol=1e-12)


@SETTINGS
@given(seed=st.integers(0, 2**31), xyz=vec3)
def test_pose_and_xyzrpy_round_trips(seed, xyz):
    rng = np.random.default_rng(seed)
    T = _random_T(rng, 1)[0]
    T[:3, 3] = xyz
    p, q = se3.transform_to_pose(T)
    np.testing.assert_allclose(se3.pose_to_transform(p, q), T, atol=1e-13)
    a, b = se3.transform_to_xyzrpy(T)
    np.testing.assert_allclose(se3.xyzrpy_to_transform(a, b), T, atol=1e-12)


@SETTINGS
@given(seed=st.integers(0, 2**31))
def test_invert_compose_identity(seed):
    rng = np.random.default_rng(seed)
    A, B = _random_T(rng, 5), _random_T(rng, 5)
    np.testing.assert_allclose(se3.compose(se3.invert(A), A), np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-14)
    np.testing.assert_allclose(se3.compose(A, se3.invert(A)), np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-14)
    np.testing.assert_allclose(se3.invert(se3.compose(A, B)), se3.compose(se3.invert(B), se3.invert(A)), atol=1e-13)
    np.testing.assert_allclose(se3.invert(A), np.linalg.inv(A), atol=1e-13)


@SETTINGS
@given(seed=st.integers(0, 2**31), axis=rotvecs, angle=st.floats(1e-7, 3.0), dp=vec3)
def test_pose_error_of_known_perturbation(seed, axis, angle, dp):
    rng = np.random.default_rng(seed)
    Tb = _random_T(rng, 1)[0]
    Ta = Tb.copy()
    Ta[:3, :3] = _rot(axis, angle) @ Tb[:3, :3]  # rotation error in the base frame
    Ta[:3, 3] += dp * 1e-3
    pos_mm, ang_deg = se3.pose_error(Ta, Tb)
    assert pos_mm == pytest.approx(np.linalg.norm(dp), rel=1e-9, abs=1e-9)
    assert ang_deg == pytest.approx(math.degrees(angle), rel=1e-8, abs=1e-9)
    np.testing.assert_allclose(se3.rotation_difference_rotvec(Ta[:3, :3], Tb[:3, :3]), axis * angle, atol=1e-9)


@SETTINGS
@given(seed=st.integers(0, 2**31), axis=rotvecs, angle=st.floats(0, 3.0), dp=vec3)
def test_ikpy_metric_closed_form(seed, axis, angle, dp):
    """sum of squared element differences = |dp_mm|^2 + ||R_a - R_b||_F^2 = |dp_mm|^2 + 4 (1 - cos angle)."""
    rng = np.random.default_rng(seed)
    Tb = _random_T(rng, 1)[0]
    Ta = Tb.copy()
    Ta[:3, :3] = _rot(axis, angle) @ Tb[:3, :3]
    Ta[:3, 3] += dp * 1e-3
    expected = np.dot(dp, dp) + 4 * (1 - math.cos(angle))
    assert se3.ikpy_metric(Ta, Tb) == pytest.approx(expected, rel=1e-9, abs=1e-12)
    assert se3.ikpy_metric(Tb, Tb) == 0.0


def test_elementary_rotations_batched():
    a = np.linspace(-3, 3, 7)
    for f, ax in ((se3.rotx, "x"), (se3.roty, "y"), (se3.rotz, "z")):
        np.testing.assert_allclose(f(a)[:, :3, :3], Rotation.from_euler(ax, a[:, None]).as_matrix(), atol=1e-15)
    T = se3.trans(np.arange(3.0), 1.0, 2.0)
    assert T.shape == (3, 4, 4)
    np.testing.assert_array_equal(T[:, :3, 3], np.stack([np.arange(3.0), np.ones(3), 2 * np.ones(3)], -1))


# --------------------------------------------------------------------------- torch twins


@SETTINGS
@given(axis=rotvecs, angle=st.floats(0, math.pi - 1e-3))
def test_so3_exp_log_torch_match_scipy(axis, angle):
    v = axis * angle
    R = se3.so3_exp_torch(torch.as_tensor(v, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), atol=1e-14)
    w = se3.so3_log_torch(torch.as_tensor(Rotation.from_rotvec(v).as_matrix(), dtype=torch.float64)).numpy()
    np.testing.assert_allclose(w, v, atol=1e-9)


def test_so3_torch_small_angles_and_batches():
    rng = np.random.default_rng(0)
    for scale in (0.0, 1e-12, 1e-8, 1e-5, 1e-3, 0.5):
        V = rng.normal(size=(20, 3)) * scale
        R = se3.so3_exp_torch(torch.as_tensor(V)).numpy()
        np.testing.assert_allclose(R, Rotation.from_rotvec(V).as_matrix(), atol=1e-15)
        np.testing.assert_allclose(se3.so3_log_torch(torch.as_tensor(R)).numpy(), V, atol=1e-12)


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 0.3])
def test_so3_torch_gradients(scale):
    g = torch.Generator().manual_seed(1)
    v = (torch.randn(4, 3, generator=g, dtype=torch.float64) * scale).requires_grad_(True)
    assert torch.autograd.gradcheck(se3.so3_exp_torch, (v,), eps=1e-7 * max(scale, 1e-3), atol=1e-6)
    R = torch.as_tensor(Rotation.from_rotvec(v.detach().numpy()).as_matrix()).requires_grad_(True)
    # log restricted to rotations: check the gradient through exp(log(.)) composition
    w = se3.so3_log_torch(se3.so3_exp_torch(v))
    (gw,) = torch.autograd.grad(w.sum(), v)
    assert torch.isfinite(gw).all()
    np.testing.assert_allclose(gw.numpy(), np.ones((4, 3)), atol=1e-6)  # log(exp(v)) = v
    out = se3.so3_log_torch(R)
    (gR,) = torch.autograd.grad(out.sum(), R)
    assert torch.isfinite(gR).all()


def test_so3_torch_gradient_at_zero_is_finite():
    v = torch.zeros(2, 3, dtype=torch.float64, requires_grad=True)
    R = se3.so3_exp_torch(v)
    (g,) = torch.autograd.grad((R * torch.arange(9.0, dtype=torch.float64).reshape(3, 3)).sum(), v)
    assert torch.isfinite(g).all()
    # d exp(v)/dv at 0 = hat(e_i): sum_ij W_ij hat(e_k)_ij = W[2,1]-W[1,2], W[0,2]-W[2,0], W[1,0]-W[0,1]
    W = np.arange(9.0).reshape(3, 3)
    np.testing.assert_allclose(g.numpy()[0], [W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]], atol=1e-12)
    w = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    out = se3.so3_log_torch(se3.so3_exp_torch(w))
    (gw,) = torch.autograd.grad(out.sum(), w)
    np.testing.assert_allclose(gw.numpy(), np.ones(3), atol=1e-12)


def test_single_rotation_paths_agree_with_scipy():
    """The plain-float path for ONE rotation (real-time code) gives scipy's numbers: quaternion and
    rotation vector bit for bit on rotations (incl. 180 degree turns and tiny angles), the matrix of a
    quaternion to rounding; a matrix that is not a rotation still goes to scipy."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    R = list(Rotation.random(500, rng).as_matrix())
    R += [np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1]),
          Rotation.from_rotvec([1e-5, 0, 0]).as_matrix(), Rotation.from_rotvec([0, np.pi - 1e-9, 0]).as_matrix(),
          Rotation.from_rotvec([2e-4, -1e-4, 3e-4]).as_matrix()]
    for M in R:
        ref = Rotation.from_matrix(M[None])
        q = ref.as_quat(canonical=True, scalar_first=True)[0]
        assert np.array_equal(se3.matrix_to_quat(M), q)
        assert np.array_equal(se3.matrix_to_rotvec(M[None])[0], ref.as_rotvec()[0])
        assert np.abs(se3.quat_to_matrix(q) - ref.as_matrix()[0]).max() < 2e-15
    skew = R[0] + 1e-6  # not a rotation: scipy's projection, the same as in a batch
    assert np.array_equal(se3.matrix_to_quat(skew), se3.matrix_to_quat(np.stack([skew, skew]))[0])
    assert se3.matrix_to_quat(np.eye(3)[None]).shape == (1, 4) and se3.matrix_to_rotvec(np.eye(3)).shape == (3,)
