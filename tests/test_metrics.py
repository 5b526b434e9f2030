"""hykin.metrics against numpy-computed statistics."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hykin.evaluation.metrics import (
    ErrorStats,
    MetricsError,
    compare,
    error_stats,
    format_table,
    pose_errors,
    stats_from_errors,
)
from hykin.geometry import se3


def _pair(n=257, seed=0):
    rng = np.random.default_rng(seed)
    T = se3.make_transform(Rotation.random(n, random_state=seed).as_matrix(), rng.uniform(-1, 1, (n, 3)))
    dp = rng.normal(0, 1e-3, (n, 3))
    dr = rng.normal(0, 2e-3, (n, 3))
    T2 = se3.make_transform(se3.rotvec_to_matrix(dr) @ T[:, :3, :3], T[:, :3, 3] + dp)
    return T2, T, dp, dr


def test_pose_errors_match_definitions():
    T2, T, dp, dr = _pair()
    pos, ang = pose_errors(T2, T)
    np.testing.assert_allclose(pos, np.linalg.norm(dp, axis=1) * 1e3, rtol=1e-9)
    np.testing.assert_allclose(ang, np.degrees(np.linalg.norm(dr, axis=1)), rtol=1e-7)


def test_error_stats_vs_numpy():
    T2, T, dp, dr = _pair()
    s = error_stats(T2, T)
    pos = np.linalg.norm(dp, axis=1) * 1e3
    ang = np.degrees(np.linalg.norm(dr, axis=1))
    assert s.n == len(pos)
    np.testing.assert_allclose([s.pos_mean_mm, s.pos_std_mm, s.pos_p95_mm, s.pos_max_mm],
                               [pos.mean(), pos.std(), np.percentile(pos, 95), pos.max()], rtol=1e-9)
    np.testing.assert_allclose([s.ang_mean_deg, s.ang_std_deg, s.ang_p95_deg, s.ang_max_deg],
                               [ang.mean(), ang.std(), np.percentile(ang, 95), ang.max()], rtol=1e-7)
    d = s.to_dict()
    assert d["n"] == s.n and d["pos_p95_mm"] == s.pos_p95_mm


def test_position_only_and_position_arrays():
    T2, T, dp, _ = _pair(50)
    s1 = error_stats(T2, T, position_only=True)
    s2 = error_stats(T2[:, :3, 3], T[:, :3, 3])
    assert s1.ang_mean_deg is None and s2.ang_mean_deg is None and not s1.has_orientation
    np.testing.assert_allclose(s1.pos_mean_mm, np.linalg.norm(dp, axis=1).mean() * 1e3, rtol=1e-9)
    assert s1 == s2


def test_compare_and_table():
    before = stats_from_errors([2.0, 2.0, 2.0], [0.2, 0.2, 0.2])
    after = stats_from_errors([0.5, 0.5, 0.5], [0.05, 0.05, 0.05])
    c = compare(before, after)
    assert c["pos_mean_reduction_pct"] == pytest.approx(75.0)
    assert c["ang_max_reduction_pct"] == pytest.approx(75.0)
    assert c["pos_mean_ratio"] == pytest.approx(4.0)
    txt = format_table({"nominal": before, "hybrid": after})
    lines = txt.splitlines()
    assert len(lines) == 4 and "nominal" in lines[2] and "hybrid" in lines[3]
    assert "2.0000 ± 0.0000" in lines[2] and "0.0500" in lines[3]


def test_bad_input():
    with pytest.raises(MetricsError):
        error_stats(np.zeros((3, 4, 4)), np.zeros((4, 4, 4)))
    with pytest.raises(MetricsError):
        error_stats(np.full((2, 3), np.nan), np.zeros((2, 3)))
    with pytest.raises(MetricsError):
        stats_from_errors([])
    with pytest.raises(MetricsError):
        format_table({})
    assert isinstance(stats_from_errors([1.0]), ErrorStats)
