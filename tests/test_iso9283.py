"""ISO 9283 AP/RP against hand-computed values on tiny data."""

import numpy as np
import pytest

from hykin.evaluation.iso9283 import ISOError, iso9283_pose
from hykin.geometry import se3


def _T(xyz_mm, rpy_deg):
    return se3.xyzrpy_to_transform(np.asarray(xyz_mm, float) * 1e-3, np.radians(rpy_deg))


def _data():
    # P1 commanded at the origin; three cycles at (1,0,0), (0,2,0), (0,0,3) mm, rolled 0.1/0.2/0.3 deg
    C1 = _T([0, 0, 0], [0, 0, 0])
    att1 = [_T([1, 0, 0], [0.1, 0, 0]), _T([0, 2, 0], [0.2, 0, 0]), _T([0, 0, 3], [0.3, 0, 0])]
    # P2 commanded at yaw 179.9 deg: attained yaw 179.95 and -179.95 (= 180.05) -> deviations 0.05, 0.15
    C2 = _T([500, 0, 200], [0, 0, 179.9])
    att2 = [_T([500, 0, 200], [0, 0, 179.95]), _T([500, 0, 200], [0, 0, -179.95])]
    C = np.stack([C1, C2, C1, C2, C1])
    A = np.stack([att1[0], att2[0], att1[1], att2[1], att1[2]])
    ids = np.array(["P1", "P2", "P1", "P2", "P1"])
    return C, A, ids


def test_hand_computed():
    C, A, ids = _data()
    r = iso9283_pose(C, A, ids)
    assert r.pose_ids == ["P1", "P2"]
    assert r.n.tolist() == [3, 2]
    # P1: barycentre (1/3, 2/3, 1) mm
    np.testing.assert_allclose(r.ap_xyz_mm[0], [1 / 3, 2 / 3, 1], atol=1e-9)
    assert r.ap_mm[0] == pytest.approx(np.sqrt(14 / 9), abs=1e-9)
    l = np.sqrt(np.array([17, 26, 41]) / 9)
    assert r.l_mean_mm[0] == pytest.approx(l.mean(), abs=1e-9)
    s_l = np.sqrt(((l - l.mean()) ** 2).sum() / 2)
    assert r.rp_mm[0] == pytest.approx(l.mean() + 3 * s_l, abs=1e-9)
    np.testing.assert_allclose(r.ap_abc_deg[0], [0.2, 0, 0], atol=1e-9)
    np.testing.assert_allclose(r.rp_abc_deg[0], [0.3, 0, 0], atol=1e-9)  # 3 * S_a, S_a = 0.1
    # P2: wrap-around at 180 deg
    assert r.ap_mm[1] == pytest.approx(0, abs=1e-9)
    np.testing.assert_allclose(r.ap_abc_deg[1], [0, 0, 0.1], atol=1e-9)
    np.testing.assert_allclose(r.s_abc_deg[1], [0, 0, np.std([0.05, 0.15], ddof=1)], atol=1e-9)
    d = r.to_dict()
    assert d["P1"]["AP_P_mm"] == pytest.approx(np.sqrt(14 / 9))
    txt = r.format()
    assert "P1" in txt and "P2" in txt and len(txt.splitlines()) == 4


def test_rotvec_mode_agrees_for_small_deviations():
    C, A, ids = _data()
    e, v = iso9283_pose(C, A, ids), iso9283_pose(C, A, ids, orientation="rotvec")
    np.testing.assert_allclose(v.ap_abc_deg, e.ap_abc_deg, atol=1e-6)
    np.testing.assert_allclose(v.rp_abc_deg, e.rp_abc_deg, atol=1e-6)
    np.testing.assert_allclose(v.rp_mm, e.rp_mm)


def test_errors():
    C, A, ids = _data()
    with pytest.raises(ISOError, match="at least 2"):
        iso9283_pose(C[:4], A[:4], np.array(["P1", "P2", "P1", "P3"]))
    C2 = C.copy()
    C2[2, 0, 3] += 1e-3
    with pytest.raises(ISOError, match="commanded poses differ"):
        iso9283_pose(C2, A, ids)
    with pytest.raises(ISOError):
        iso9283_pose(C, A[:3], ids)
    with pytest.raises(ISOError):
        iso9283_pose(C, A, ids, orientation="quat")
