"""The report and ``evaluate`` output on tracker data of two stations and two tools (probe AF):
outlier rows in evaluation.json numbered as the text names them, accuracy per station / per tool, the
further stations' and tools' frames in the calibration table (identified, no deviation from a nominal
they do not have), the calibration's "before" named and the robot's own deviations listed apart from the
set-up's frames, outliers left out of the where-is-the-error figures, the std convention, the worst
error's digits, and test poses in a gap of a folded joint's training data.

Every figure is checked against numpy in this file: the model's per-row errors are recomputed from its
predictions and station / tool matrices, statistics with numpy, gaps from the trained range by hand.
"""

from __future__ import annotations

import json
import re
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_stations import campaign

from hykin.geometry import se3

#: the two tools (flange -> TCP): the reference K1 and K2, turned and 8 cm away
TOOLS = {"K1": se3.trans(0.01, 0.02, 0.12),
         "K2": se3.make_transform(se3.rotvec_to_matrix(np.array([0.1, 0.0, 0.3])), np.array([-0.04, 0.03, 0.09]))}
BAD = [17, 63]  # 0-based test rows given a 5 mm lost-beam error: data rows 18 and 64


@pytest.fixture(scope="module")
def fitted():
    """A hybrid model fitted on 300 poses from stations A (reference) and B with tools K1 (reference) and K2,
    and 100 test poses of the same set-up whose rows :data:`BAD` are 5 mm off, with a pose_id column."""
    from hykin.hybrid.model import HybridModel
    from hykin.io.dataset import Dataset

    nom, data, _, _ = campaign(n=400, seed=1, tools=TOOLS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = HybridModel(nom, seed=0, recipe_kw={"max_epochs": 2, "min_steps": 0}, uncertainty=False).fit(
            data.subset(np.arange(300)), progress=False)
    te = data.subset(np.arange(300, 400))
    T = te.poses()
    T[BAD, :3, 3] += np.array([0.003, 0.0, 0.004])  # 5 mm
    ids = np.array([""] * len(te), dtype=object)
    ids[BAD[0]] = "P7"
    test = Dataset.from_poses(te.q, T, extra={"station": te.extra["station"], "tool": te.extra["tool"], "pose_id": ids},
                              source="test.csv")
    return m, test


@pytest.fixture(scope="module")
def evaluated(fitted):
    from hykin.evaluation.evaluate import evaluate_model

    m, test = fitted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return evaluate_model(m, test)


def _own_errors(m, test) -> tuple[np.ndarray, np.ndarray]:
    """Hybrid position (mm) and orientation (deg) errors by hand: each measured pose moved into the reference
    station's frame and onto the reference tool with the model's station / tool matrices, against predict."""
    fr = m.station_frames_
    st, tl = np.asarray(test.extra["station"]), np.asarray(test.extra["tool"])
    B = {s: fr.base_of(s) for s in fr.station_labels}
    E = {t: fr.tool_of(t) for t in fr.tool_labels}
    L = np.stack([B[fr.station_labels[0]] @ np.linalg.inv(B[s]) for s in st])
    R = np.stack([np.linalg.inv(E[t]) @ E[fr.tool_labels[0]] for t in tl])
    T_meas = L @ test.poses() @ R
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        T = m.predict(test.q)
    pos = np.linalg.norm(T[:, :3, 3] - T_meas[:, :3, 3], axis=1) * 1e3
    ang = np.degrees(Rotation.from_matrix(T[:, :3, :3] @ np.transpose(T_meas[:, :3, :3], (0, 2, 1))).magnitude())
    return pos, ang


def test_outlier_json_names_the_texts_rows_and_pose_ids(evaluated):
    """evaluation.json's outliers are the 1-based data rows the text names (18, 64), with the 0-based
    indices under a key that says so and the rows' pose ids (old: ``rows`` [17, 63], 0-based, unnamed)."""
    d = json.loads(evaluated.json())["outliers"]
    assert d["data_rows"] == [r + 1 for r in BAD] and d["index_0based"] == BAD and "rows" not in d
    assert d["pose_id"] == ["P7", ""]
    assert f"data rows {BAD[0] + 1}, {BAD[1] + 1}" in evaluated.outlier_line()


def test_accuracy_per_station_and_tool_against_numpy(fitted, evaluated):
    """n, mean, p95, max position and mean orientation per station and per tool (hybrid row) against the
    errors recomputed by hand; the reference labels named in the terminal table and the JSON."""
    m, test = fitted
    pos, ang = _own_errors(m, test)
    np.testing.assert_allclose(evaluated.errors["hybrid"][0], pos, rtol=1e-6, atol=1e-9)
    d = json.loads(evaluated.json())
    for col, ref in (("station", "A"), ("tool", "K1")):
        g = d[f"per_{col}"]
        assert g["reference"] == ref and list(g["labels"])[0] == ref
        labels = np.asarray(test.extra[col])
        for lab in np.unique(labels):
            sel = labels == lab
            s = g["labels"][lab]["hybrid"]
            assert s["n"] == int(sel.sum())
            assert s["pos_mean_mm"] == pytest.approx(pos[sel].mean(), rel=1e-6)
            assert s["pos_p95_mm"] == pytest.approx(np.percentile(pos[sel], 95), rel=1e-6)
            assert s["pos_max_mm"] == pytest.approx(pos[sel].max(), rel=1e-6)
            assert s["ang_mean_deg"] == pytest.approx(ang[sel].mean(), rel=1e-5)
    table = evaluated.table()
    assert "reference station A, reference tool K1" in table and "| station | B | hybrid | 40 |" in table
    assert "population standard deviation (ddof = 0)" in table


def test_further_frames_in_calibration_table_have_no_deviation(fitted):
    """station[B].* and tool[K2].*: no nominal, no deviation, no "differs from nominal" note; identified =
    the model's frame for B / K2 (xyz mm, rotation vector deg), the .x row's note giving the frame in rpy.
    The summary lists the robot's own parameters apart from the frames, and names what "before" is."""
    from hykin.evaluation.report_calibration import calibration_rows, calibration_summary

    m, _ = fitted
    cal = m.calibration_.to_dict()
    rows = {r.name: r for r in calibration_rows(cal, m.nominal, m.robot_)}
    fr = m.station_frames_
    for prefix, T in (("station[B]", fr.base_of("B")), ("tool[K2]", fr.tool_of("K2"))):
        rv = np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())
        want = dict(zip(("x", "y", "z", "rx", "ry", "rz"), [*(T[:3, 3] * 1e3), *rv]))
        for f, v in want.items():
            r = rows[f"{prefix}.{f}"]
            assert r.nominal is None and r.deviation is None and r.identified == pytest.approx(v, abs=1e-9)
            assert "nominal (" not in r.notes and "no robot-file value" in r.notes
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)
        assert f"rpy {', '.join(f'{v:.4f}' for v in rpy)} deg" in rows[f"{prefix}.x"].notes
    text = " ".join(calibration_summary(cal, list(rows.values()), (0.74, "on the test data")))
    own = text.split("Largest significant deviations of the robot's own parameters")[1].split(".")[0]
    assert not re.search(r"\b(base|tool|station)[.\[]", own)
    assert "“before” is the robot file as written" in text and "0.74 mm on the test data" in text


def test_report_figures_leave_outliers_out_and_name_them(fitted, evaluated, monkeypatch):
    """The per-joint and workspace figures get every row but the named outliers (the caption says so), the
    per-station table and its reference are in the report, std is said to be ddof 0 and the worst error
    keeps 3 significant digits."""
    import hykin.evaluation.report_build as rb

    m, test = fitted
    seen = {}
    real_joint, real_spatial = rb.joint_error_figure, rb.spatial_error_figure
    monkeypatch.setattr(rb, "joint_error_figure", lambda q, e, rev: seen.setdefault("joint", (q, e)) and real_joint(q, e, rev))
    monkeypatch.setattr(rb, "spatial_error_figure", lambda x, e, lab: seen.setdefault("spatial", (x, e)) and real_spatial(x, e, lab))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rep, res = rb.build_report(m, test, res=evaluated, ik_targets=0)
    keep = np.setdiff1d(np.arange(len(test)), BAD)
    np.testing.assert_array_equal(seen["joint"][0], np.asarray(test.q)[keep])
    np.testing.assert_array_equal(seen["joint"][1]["hybrid"], evaluated.errors["hybrid"][0][keep])
    assert len(seen["spatial"][1]) == len(keep)
    page = rep.html()
    assert f"data rows {BAD[0] + 1}, {BAD[1] + 1}" in page and "left out here" in page
    assert "reference station A, reference tool K1" in page and "ddof = 0" in page
    worst = evaluated.errors["hybrid"][0].max()
    assert f"worst {worst:#.3g}".rstrip(".") + " mm" in page


def test_gap_of_a_folded_joint_named_as_a_gap():
    """A folded joint trained on −27.56 … 330° (a 2.44° gap from −30 to −27.56°): a test pose there is "in a
    gap of the training data", one beyond another joint's range is not."""
    from hykin.evaluation.report_accuracy import fold_gaps, outside_split
    from hykin.evaluation.report_summary import support_sentence

    lo, hi = np.radians([-90.0, -27.56]), np.radians([90.0, 330.0])
    q = np.radians([[0.0, -29.0], [100.0, 10.0], [0.0, 10.0]])  # in the gap; beyond joint 1; inside (a hole)

    def range_excess(qq):
        return np.maximum(0, np.maximum(lo - qq, qq - hi)) / (hi - lo)

    q_net = q.copy()
    q_net[:, 1] = np.where(q[:, 1] < lo[1], q[:, 1] + 2 * np.pi, q[:, 1])  # folded as the networks see it
    model = SimpleNamespace(wrap_centre_=np.array([np.nan, np.radians(151.22)]), support_lower_=lo, support_upper_=hi,
                            input_mask_=np.array([True, True]), range_excess=lambda qq: range_excess(q_net))
    (a, b), = fold_gaps(model).values()
    assert (a, b) == pytest.approx((330.0 - 360.0, -27.56))
    split = outside_split(model, q, np.array([True, True, True]))
    assert split["gap"].tolist() == [True, False, False] and split["range"].tolist() == [False, True, False]
    assert split["holes"].tolist() == [False, False, True]
    res = SimpleNamespace(support_distance=np.array([0.1, 0.2, 0.05]), n=3)
    s = support_sentence(res, SimpleNamespace(q=q), model, np.array([1.0, 2.0, 3.0]))
    assert "1 in a gap of the training data (joint 2" in s and "2.44° gap from -30 to -27.56°" in s
    assert "1 beyond a joint's trained range" in s and "1 between training poses" in s


def test_a_joint_of_less_than_a_turn_has_no_fold_gap_and_only_gaps_with_test_poses_are_named():
    """Probe s41 AN: a ±175° joint (folded input, but less than a turn) was said to "cover the whole turn
    except a 12.5° gap from -186.4 to -173.9°", and the summary named gaps no test pose lies in."""
    from hykin.evaluation.report_accuracy import fold_gaps
    from hykin.evaluation.report_summary import support_sentence

    lo, hi = np.radians([-173.9, -27.56, -20.0]), np.radians([173.6, 330.0, 335.0])
    robot = SimpleNamespace(dof=3, lower=np.radians([-175.0, -400.0, -400.0]), upper=np.radians([175.0, 400.0, 400.0]))
    q = np.radians([[0.0, -29.0, 0.0]])  # in joint 2's gap only

    def range_excess(qq):
        qn = qq.copy()
        qn[:, 1:] = np.where(qq[:, 1:] < lo[1:], qq[:, 1:] + 2 * np.pi, qq[:, 1:])
        return np.maximum(0, np.maximum(lo - qn, qn - hi)) / (hi - lo)

    model = SimpleNamespace(wrap_centre_=np.radians([0.0, 151.22, 157.5]), support_lower_=lo, support_upper_=hi,
                            input_mask_=np.array([True, True, True]), range_excess=range_excess, robot_=robot)
    assert sorted(fold_gaps(model)) == [1, 2]  # joint 1 (±175°) is not folded over a turn
    res = SimpleNamespace(support_distance=np.array([0.1]), n=1)
    s = support_sentence(res, SimpleNamespace(q=q), model, np.array([1.0]))
    assert "joint 2: its training data" in s and "joint 3" not in s and "joint 1" not in s, s


def test_a_fold_gap_is_said_on_the_turn_nearest_zero():
    """Probe s41 AP: a gap said as "-285.4 to -277.1°" for test poses at +75 … +80° (the folded numbers)."""
    from hykin.evaluation.report_accuracy import fold_gaps

    lo, hi = np.radians([-277.1]), np.radians([74.6])
    robot = SimpleNamespace(dof=1, lower=np.radians([-400.0]), upper=np.radians([400.0]))
    model = SimpleNamespace(wrap_centre_=np.radians([-101.25]), support_lower_=lo, support_upper_=hi,
                            input_mask_=np.array([True]), robot_=robot)
    (a, b), = fold_gaps(model).values()
    assert (a, b) == pytest.approx((74.6, 82.9))
