"""The report on data measured in a tracker's frame (robot base far from the tracker origin, turned):
its base-frame figures (reach hotspot, x/y/z components, positions plot, ISO AP_x/y/z) against the
same figures computed by hand from the simulated base-frame data, and the nominal row named as the
evaluation labels it (nominal + fitted frames), not meaningful on very few distinct poses."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from hykin.geometry import se3

# the tracker frame: the robot base 4.2 m away from its origin, turned 35° about z
W = se3.trans(4.2, -2.5, 0.8) @ se3.rotz(np.radians(35.0))


def _to_tracker(ds):
    """A base-frame Dataset -> the same measurements in the tracker frame (W · T)."""
    from hykin.io.dataset import Dataset

    xyz, quat = se3.transform_to_pose(W @ ds.poses())
    return Dataset(q=ds.q, xyz_m=xyz, quat_wxyz=quat, extra=dict(ds.extra), source=ds.source)


def _hand_bins(x, e, n_bins=6):
    """Equal-width bins of x: (lo, hi, mean e, count) of each non-empty bin, by a loop."""
    edges = np.linspace(x.min(), x.max(), n_bins + 1)
    out = []
    for b in range(n_bins):
        last = b == n_bins - 1
        sel = (x >= edges[b]) & ((x <= edges[b + 1]) if last else (x < edges[b + 1]))
        out.append((edges[b], edges[b + 1], e[sel].mean() if sel.any() else np.nan, int(sel.sum())))
    return out


def _measure(robot, q, pose_id=None, noise_m=0.0, rng=None):
    """Base-frame measurements of ``robot`` at ``q`` (a Dataset), positions with Gaussian noise ``noise_m``."""
    from hykin.io.dataset import Dataset
    from hykin.kinematics.classical import classical_fk

    xyz, quat = se3.transform_to_pose(classical_fk(robot, q))
    if noise_m:
        xyz = xyz + rng.normal(0.0, noise_m, xyz.shape)
    return Dataset(q=q, xyz_m=xyz, quat_wxyz=quat, extra={} if pose_id is None else {"pose_id": pose_id})


@pytest.fixture(scope="module")
def tracker(tmp_path_factory):
    """A hybrid model fitted on noise-free tracker-frame data of a known robot (the rx160 with link deviations that
    do not mix with its base), whose robot file puts the base 20 mm and 0.3° off the truth (so the
    calibration identifies the base and the evaluation fits the nominal row's frames); base-frame and
    tracker-frame test sets (150 random poses + 5 poses x 4 cycles, 20 µm position noise), and an ISO-like set of 5 poses x
    6 cycles."""
    from hykin.calibration.params import apply_deviations
    from hykin.hybrid.model import HybridModel
    from hykin.io.robot_file import load_robot
    from hykin.sim.sampling import sample

    rob = load_robot("rx160")
    truth = apply_deviations(rob, {"a2": 6e-4, "a3": -4e-4, "d4": 5e-4, "theta3": 3e-4, "alpha3": -2e-4})
    rng = np.random.default_rng(1)
    train_b = _measure(truth, sample("uniform", rob, 500, rng))
    q = np.clip(sample("random", rob, 150, rng), train_b.q.min(0), train_b.q.max(0))
    test_b = _measure(truth, np.vstack([q, np.repeat(q[:5], 4, axis=0)]),
                      np.r_[np.arange(150) + 100, np.repeat(np.arange(5) + 1, 4)].astype(float), 2e-5, rng)
    iso_b = _measure(truth, np.repeat(q[10:15], 6, axis=0), np.repeat(np.arange(5) + 1, 6).astype(float), 2e-5, rng)
    off = se3.trans(0.02, -0.01, 0.005) @ se3.rotz(np.radians(0.3))
    nominal = rob.copy(base=W @ off @ rob.base)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = HybridModel(nominal, seed=0, recipe_kw={"max_epochs": 3}).fit(_to_tracker(train_b), progress=False)
    d = tmp_path_factory.mktemp("frames")
    return m, test_b, _to_tracker(test_b), _to_tracker(iso_b), d


@pytest.fixture(scope="module")
def evaluated(tracker):
    from hykin.evaluation.evaluate import evaluate_model

    m, _, test_t, _, _ = tracker
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return evaluate_model(m, test_t)


def test_base_frame_is_the_calibrated_base(tracker):
    """The report's base frame is the model's calibrated base in the tracker frame: the truth W·base
    (robot file 20 mm off), so mapping the tracker data back gives the simulated base-frame data."""
    from hykin.evaluation.report_accuracy import base_frame

    m, test_b, test_t, _, _ = tracker
    fr = base_frame(m)
    assert fr.is_base and "calibrated" in fr.words
    np.testing.assert_allclose(fr.points(test_t.xyz_m), test_b.xyz_m, atol=2e-5)  # 20 µm: calibration accuracy
    assert np.abs(fr.points(test_t.xyz_m) - test_b.xyz_m).max() < 1e-3  # far closer than the file's 20 mm


def test_reach_hotspot_in_base_frame(tracker):
    """Errors planted where the base-frame reach is largest: the hotspot is that bin, with bounds, mean
    and count of a hand binning of the base-frame positions (not the tracker's 4–6 m distances)."""
    from hykin.evaluation.report_accuracy import base_frame, reach_hotspot

    m, test_b, test_t, _, _ = tracker
    r = np.hypot(test_b.xyz_m[:, 0], test_b.xyz_m[:, 1])
    e = np.where(r > r.min() + 0.85 * np.ptp(r), 0.05, 0.01)
    bins = _hand_bins(r, e)
    k = int(np.nanargmax([b[2] if b[3] >= max(0.05 * len(r), 3) else -np.inf for b in bins]))
    h = reach_hotspot(test_t.xyz_m, e, frame=base_frame(m))
    assert h.lo == pytest.approx(bins[k][0], abs=1e-4) and h.hi == pytest.approx(bins[k][1], abs=1e-4)
    assert h.mean_mm == pytest.approx(bins[k][2]) and h.n == bins[k][3]
    assert h.hi < 2.0  # an rx160's reach, not the distance from the tracker origin
    r_t = np.hypot(test_t.xyz_m[:, 0], test_t.xyz_m[:, 1])
    assert r_t.min() > 3.0  # the tracker-frame distances the old report binned


def test_summary_reach_is_base_frame(tracker, evaluated):
    """The summary's reach sentence (built from the evaluation) names the hand-binned base-frame range."""
    from copy import deepcopy

    from hykin.evaluation.report_summary import accuracy_sentences

    m, test_b, test_t, _, _ = tracker
    res = deepcopy(evaluated)
    r = np.hypot(test_b.xyz_m[:, 0], test_b.xyz_m[:, 1])
    e = np.where(r > r.min() + 0.85 * np.ptp(r), 0.05, 0.01)
    res.errors["hybrid"] = (e, res.errors["hybrid"][1])
    bins = _hand_bins(r, e)
    k = int(np.nanargmax([b[2] if b[3] >= max(0.05 * len(r), 3) else -np.inf for b in bins]))
    text = " ".join(accuracy_sentences(res, test_t, np.ones(6, bool), m))
    assert f"horizontal reach between {bins[k][0]:.3g} and {bins[k][1]:.3g} m" in text, text


def test_axis_rows_are_base_frame_components(tracker, evaluated):
    """x/y/z rows: predicted minus measured in the base frame, computed here by mapping the model's
    tracker-frame predictions with the known W and subtracting the simulated base-frame data."""
    from hykin.evaluation.report_accuracy import axis_rows, base_frame

    m, test_b, _, _, _ = tracker
    rows = {(r[0], r[1].strip()): r for r in axis_rows(evaluated.vectors, base_frame(m), evaluated.labels)}
    for key in ("hybrid", "nominal"):
        name = evaluated.labels.get(key, key)
        Tp = se3.invert(W) @ evaluated.predicted[key]
        dp = (Tp[:, :3, 3] - test_b.xyz_m) * 1e3
        dr = np.degrees(se3.rotation_difference_rotvec(Tp[:, :3, :3], test_b.rotations()))
        scale = np.abs(dp).max()
        for k, ax in enumerate("xyz"):
            v = dp[:, k]
            got = rows[(name, ax)][2:6]
            assert got == pytest.approx([v.mean(), v.std(), np.percentile(abs(v), 95), abs(v).max()], abs=2e-3 * scale), (key, ax)
        for k, ax in enumerate(("rx", "ry", "rz")):
            assert rows[(name, ax)][3] == pytest.approx(dr[:, k].std(), rel=2e-3, abs=1e-6)
    # the tracker-frame components differ (turned 35°): the old table was not base-frame
    dp_t = evaluated.vectors["nominal"][0]
    name = evaluated.labels["nominal"]
    assert abs(rows[(name, "x")][3] - dp_t[:, 0].std()) > 0.01 * dp_t[:, 0].std()


def test_iso_ap_xyz_in_base_frame(tracker, evaluated):
    """ISO AP_x/y/z of pose 1: mean attained minus commanded, both in the base frame (by hand)."""
    from hykin.evaluation.report_accuracy import base_frame, iso_rows

    m, test_b, test_t, _, _ = tracker
    rows, _ = iso_rows(test_t, evaluated.predicted, base_frame(m), evaluated.labels)
    sel = test_b.extra["pose_id"] == 1
    Tp = se3.invert(W) @ evaluated.predicted["hybrid"][sel][0]
    ap = (test_b.xyz_m[sel].mean(0) - Tp[:3, 3]) * 1e3
    row = next(r for r in rows if r[0] == "hybrid" and r[1] == "1")
    assert row[4:7] == pytest.approx(ap, abs=2e-4 * max(np.abs(ap).max(), 1e-3) + 2e-6)
    assert row[3] == pytest.approx(np.linalg.norm(ap), rel=1e-3, abs=1e-6)


@pytest.mark.slow  # a full report build (5 s): the default suite keeps the wording and few-poses checks
def test_report_positions_plot_labels_and_json(tracker, evaluated, monkeypatch):
    """The full report: the positions plot gets base-frame positions; the nominal row is named
    "nominal + fitted frames" in tables and words; evaluation.json keeps the key "nominal"."""
    from hykin.evaluation import report_build
    from hykin.evaluation.evaluate import NOMINAL_FITTED

    m, test_b, test_t, _, d = tracker
    assert evaluated.labels["nominal"] == NOMINAL_FITTED  # the robot file's frames are 20 mm off
    seen = {}
    orig = report_build.spatial_error_figure

    def spy(xyz, e, label):
        seen["xyz"] = np.array(xyz)
        return orig(xyz, e, label)

    monkeypatch.setattr(report_build, "spatial_error_figure", spy)
    rep, res = report_build.build_report(m, test_t, res=evaluated, ik_targets=0)
    path = report_build.write_report(rep, d / "rep", res)
    np.testing.assert_allclose(seen["xyz"], test_b.xyz_m, atol=2e-5)
    html = path.read_text()
    assert "<td class='text'>nominal + fitted frames</td>" in html
    assert "nominal kinematics with base and tool fitted to these poses" in html
    assert "Test positions (base frame" in html
    h, n = evaluated.stats["hybrid"], evaluated.stats["nominal"]
    removed = 100 * (1 - h.pos_mean_mm / n.pos_mean_mm)
    pct = f"{removed:.1f} %" if removed < 99.9 else f"{removed:.4g} %"
    assert f"removes {pct} of the mean position error of the nominal + fitted frames row" in html
    assert "not meaningful" not in html
    js = json.loads((d / "rep" / "evaluation.json").read_text())
    assert set(js["stats"]) == {"nominal", "calibrated", "hybrid"} and js["labels"]["nominal"] == NOMINAL_FITTED


def test_few_distinct_poses_nominal_not_meaningful(tracker):
    """5 distinct poses (ISO cycles): a base/tool fit absorbs the nominal error, so the report says the
    nominal figure is not meaningful and claims no share removed."""
    from hykin.evaluation.evaluate import evaluate_model
    from hykin.evaluation.report_accuracy import distinct_poses
    from hykin.evaluation.report_build import build_report

    m, _, _, iso_t, _ = tracker
    assert distinct_poses(iso_t.q) == 5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = evaluate_model(m, iso_t)
        rep, _ = build_report(m, iso_t, res=res, ik_targets=0)
    html = rep.html()
    assert "rests on only 5 distinct test poses" in html and "is not meaningful" in html
    assert "removes" not in html


def test_robot_model_fitted_base():
    """A plain robot file whose base is the identity, data in the tracker frame: the evaluation fits
    the nominal row's frames and the report's base frame is that fitted base (≈ W)."""
    from hykin.evaluation.evaluate import NOMINAL_FITTED, evaluate_model
    from hykin.evaluation.report_accuracy import base_frame
    from hykin.io.dataset import Dataset
    from hykin.kinematics.classical import classical_fk
    from hykin.io.robot_file import load_robot
    from hykin.sim.sampling import sample

    rob = load_robot("rx160")
    q = sample("random", rob, 60, np.random.default_rng(2))
    xyz, quat = se3.transform_to_pose(W @ classical_fk(rob, q))
    ds = Dataset(q=q, xyz_m=xyz, quat_wxyz=quat)
    res = evaluate_model(rob.copy(base=np.eye(4)), ds)
    assert res.labels["nominal"] == NOMINAL_FITTED
    fr = base_frame(rob.copy(base=np.eye(4)), ds, res.labels)
    np.testing.assert_allclose(fr.T, W @ rob.base, atol=1e-6)
    np.testing.assert_allclose(fr.points(xyz), classical_fk(rob, q)[:, :3, 3], atol=1e-6)
