"""Fitting, training support and model files (probe X, session 40): repeated rows, the hybrid lost-beam
test, held-out row counts, a data path for ``HybridModel.fit``, joint-limit slack, fit outputs and model
files given as robots, ``--payload-kg`` without compliance. References are written here in numpy."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from hykin.geometry import se3
from hykin.hybrid import fitting
from hykin.hybrid.support import fit_support
from hykin.io.dataset import Dataset, DatasetError, validate_joints
from hykin.io.dataset_files import read_dataset, write_dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk

from cli_run import run


def _nn_p95(x: np.ndarray) -> float:
    """Reference: 95th percentile of each point's distance to its nearest other point (brute force)."""
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return float(np.percentile(d.min(1), 95))


# ----------------------------------------------------------------------------- repeated rows (X-A1)


def test_distinct_groups_and_support_spacing_of_repeated_rows():
    from hykin.hybrid.support import SAME_JOINTS, distinct_groups

    rng = np.random.default_rng(0)
    q = rng.uniform(-2, 2, (300, 6))
    np.testing.assert_array_equal(distinct_groups(q), np.arange(300))  # no repeats: one group per row
    jitter = rng.uniform(-0.02, 0.02, q.shape) * SAME_JOINTS * (q.max(0) - q.min(0))  # an encoder's jitter
    qq = np.vstack([q, q, q + jitter])  # three cycles of one plan
    g = distinct_groups(qq)
    np.testing.assert_array_equal(g[:600], np.tile(np.arange(300), 2))  # exact repeats: always one configuration
    assert np.mean(g[600:] == g[:300]) > 0.8  # jittered ones mostly (a grid cell face splits a few)
    mask = np.ones(6, dtype=bool)
    single, rep = fit_support(q, mask, 0), fit_support(qq, mask, 0)
    lo, span = q.min(0), q.max(0) - q.min(0)
    ref = _nn_p95((q - lo) / span)
    assert single.spacing == pytest.approx(ref, rel=1e-12)
    # the old spacing of the raw rows was 0 (every query "outside"); over distinct joints it is the plan's
    assert rep.spacing == pytest.approx(ref, rel=0.02)
    assert 300 <= len(rep.points) <= 360  # one point per configuration (a few split jittered ones extra)
    from hykin.hybrid.support import support_distance

    assert np.all(support_distance(rep, qq) == 0.0)  # the training joints themselves lie inside


def test_held_out_split_keeps_repeats_together_and_warns_with_counts():
    from hykin.hybrid.errors import FitWarning

    rng = np.random.default_rng(1)
    q = rng.uniform(-2, 2, (200, 6))
    z = np.zeros((200, 3))
    kw = dict(robot=None, seed=3, val_fraction=0.1, j1_axis=None)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no repeats: no warning, and the plain permutation of the rows
        sp = fitting.split_validation(q, z, None, np.zeros(200), None, **kw)
    perm = np.random.default_rng(3).permutation(200)
    np.testing.assert_array_equal(sp["iv"], perm[:20])
    qq = np.vstack([q, q])
    with pytest.warns(FitWarning, match=r"200 of 400 training rows repeat .* \(200 distinct joint vectors"):
        sp = fitting.split_validation(qq, np.zeros((400, 3)), None, np.zeros(400), None, **kw)
    rows = np.concatenate([sp["iv"], sp["iv_cal"]])  # held out: epoch selection and band calibration halves
    held = {tuple(r) for r in qq[rows]}
    trained = {tuple(r) for r in sp["qt"]}
    assert len(rows) == 40 and len(sp["qt"]) == 360 and not held & trained  # no held-out pose was trained on


# ----------------------------------------------------------------------------- HybridModel.fit(path) (X-B1)


def _exact_rows(robot, n, seed):
    q = robot.random_joints(n, np.random.default_rng(seed), margin=0.05)
    T = fk(robot, q)
    return Dataset(q=q, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source="exact")


def test_fit_takes_a_path_as_the_cli_reads_it_and_warns_on_repeats(tmp_path):
    from hykin.hybrid.errors import FitWarning
    from hykin.hybrid.model import HybridModel

    rob = load_robot("rx160")
    ds = _exact_rows(rob, 60, 2)
    path = tmp_path / "train.csv"
    write_dataset(Dataset.concat([ds, ds]), path)  # every pose measured twice
    kw = dict(calibrate=False, recipe_kw={"max_epochs": 1}, uncertainty=False, seed=1)
    with pytest.warns(FitWarning, match="60 of 120 training rows repeat"):
        a = HybridModel(rob, **kw).fit(str(path), progress=False)
    b = HybridModel(rob, **kw).fit(read_dataset(path, robot=rob), progress=False)
    qt = rob.random_joints(20, np.random.default_rng(3), margin=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        np.testing.assert_array_equal(a.predict(qt), b.predict(qt))
    assert np.all(a.support_distance(ds.q) == 0.0)  # every training pose inside its own support
    assert a.metadata["metrics"]["held_out"]["n_rows"] == 12  # 6 poses with both their copies
    with pytest.raises(TypeError, match="train must be a hykin Dataset or the path"):
        HybridModel(rob, **kw).fit(42, progress=False)


# ----------------------------------------------------------------------------- lost beams vs the hybrid (X-D1)


class _Stub:
    """A fitted-model stand-in: classical poses = truth, hybrid poses = truth + ``err`` (m)."""

    calibrate, calibrate_kw, calibration_ = True, None, None

    def __init__(self, T_true, err, dof):
        self.T, self.err = T_true, err
        self.input_mask_ = np.ones(dof, dtype=bool)
        self.support_lower_, self.support_upper_ = np.zeros(dof), np.ones(dof)

    def _netq(self, q):
        return q

    def predict_classical(self, q, temperature_c=None, **_):
        return self.T[: len(q)].copy()

    def predict(self, q, temperature_c=None, **_):
        T = self.T[: len(q)].copy()
        T[:, :3, 3] += self.err[: len(q)]
        return T


def _errors(rng, n, sigma):
    return sigma * rng.standard_normal((n, 3))


def test_clean_rows_where_the_networks_are_weak_are_not_lost_beams_but_a_beam_is():
    """400 rows: trained rows fit to 10 µm, held-out rows to 30 µm, and the 10 % near one joint limit to
    0.15 mm (networks weakest there); one interior trained row carries a 0.6 mm lost beam. The old test
    (all rows' median) named the edge rows; now only the beam is named."""
    rng = np.random.default_rng(4)
    n = 400
    q = rng.uniform(0, 1, (n, 6))
    T = np.tile(np.eye(4), (n, 1, 1))
    held = np.arange(n)[rng.permutation(n)[:40]]
    err = _errors(rng, n, 10e-6)
    err[held] = _errors(rng, 40, 30e-6)
    edge = q[:, 1] > 0.9
    err[edge] = _errors(rng, int(edge.sum()), 0.15e-3 / 1.6)
    beam = int(np.flatnonzero(~edge & ~np.isin(np.arange(n), held))[0])
    err[beam] = [0.6e-3, 0.0, 0.0]
    ds = Dataset(q=q, xyz_m=np.zeros((n, 3)), source="cell.csv")
    stub = _Stub(T, err, 6)
    e = np.linalg.norm(err, axis=1)
    typical_all = np.median(e) / 1.5382
    assert (e[edge] > 12 * typical_all).sum() >= 3  # what the old rule named: clean edge rows
    with pytest.warns(UserWarning) as rec:
        fitting.train_metrics(stub, ds, held)
    msgs = [str(w.message) for w in rec]
    assert len(msgs) == 1 and f"data rows {beam + 1} (" in msgs[0] and "1 of 360 poses" in msgs[0], msgs
    assert "the 40 rows held out from training" in msgs[0]


def test_row_scales_against_a_brute_force_reference():
    rng = np.random.default_rng(5)
    x = rng.uniform(0, 1, (120, 3))
    e = np.abs(rng.standard_normal(120)) * (1 + 3 * (x[:, 0] > 0.8))  # a region that fits worse
    e_ref = np.abs(rng.standard_normal(30)) * 2.0
    sc, s_ref = fitting.row_scales(e, e_ref, x)
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    np.fill_diagonal(d, np.inf)
    nb = np.argsort(d, axis=1)[:, :16]
    loc = np.median(e[nb], axis=1)
    ref = np.median(e_ref) / 1.5382 * np.maximum(1.0, loc / (1.25 * np.median(e)))
    assert s_ref == pytest.approx(np.median(e_ref) / 1.5382)
    np.testing.assert_allclose(sc, ref, rtol=1e-12)
    assert sc[x[:, 0] > 0.9].mean() > 1.5 * s_ref  # raised where the neighbours fit worse


# ----------------------------------------------------------------------------- held-out figures (X-A3)


def test_held_out_figures_say_their_rows_and_warn_when_too_few_or_worse():
    from hykin.hybrid.errors import FitWarning

    rng = np.random.default_rng(6)
    n = 40
    T = np.tile(np.eye(4), (n, 1, 1))
    q = rng.uniform(0, 1, (n, 6))
    ds = Dataset(q=q, xyz_m=np.zeros((n, 3)), source="t")

    class Worse(_Stub):  # classical 0.1 mm, hybrid 0.2 mm off (the networks hurt)
        def predict_classical(self, q, temperature_c=None, **_):
            T2 = self.T[: len(q)].copy()
            T2[:, :3, 3] += 0.5 * self.err[: len(q)]
            return T2

    err = _errors(rng, n, 0.2e-3 / 1.6)
    with pytest.warns(FitWarning, match="rest on 4 rows only: too few to tell whether the networks help"):
        m = fitting.held_out_metrics(_Stub(T, err, 6), ds.subset(np.arange(4)), "held_out")
    assert m["n_rows"] == 4
    with pytest.warns(FitWarning, match="on the 40 held-out rows the hybrid model is worse than the calibrated one"):
        m = fitting.held_out_metrics(Worse(T, err, 6), ds, "held_out")
    ref = np.linalg.norm(err, axis=1).mean() * 1e3
    assert m["hybrid_pos_mean_mm"] == pytest.approx(ref) and m["classical_pos_mean_mm"] == pytest.approx(ref / 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the hybrid better on enough rows: no warning
        fitting.held_out_metrics(_Stub(T, err * 0.0, 6), ds, "val")


# ----------------------------------------------------------------------------- joint limits (X-C1)


def test_joint_limits_accept_a_small_slack_with_counts_and_refuse_beyond():
    from hykin.io.dataset import JointLimitWarning

    rob = load_robot("rx160")
    q = np.zeros((5, 6))
    q[1, 1] = rob.upper[1] + np.radians(0.001)  # 0.001 deg past: a good measured row
    q[3, 4] = rob.lower[4] - np.radians(0.4)
    with pytest.warns(JointLimitWarning, match=r"2 of 5 rows .* \(q2: 1, q5: 1; at most q2 0.001 deg, q5 0.4 deg past\)"):
        validate_joints(q, rob, where="d.csv")
    q[2, 2] = rob.upper[2] + np.radians(0.6)
    with pytest.raises(DatasetError, match=r"d.csv, row 3 .*column 'q3'.*150.6 deg is outside the limits \[-150, 150\] deg"
                                           r".*widen min/max"):
        validate_joints(q, rob, where="d.csv")


# ----------------------------------------------------------------------------- CLI: outputs, model files, payload


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    from hykin.hybrid.model import HybridModel

    d = tmp_path_factory.mktemp("s40")
    rob = load_robot("rx160")
    ds = _exact_rows(rob, 80, 7)
    write_dataset(ds, d / "train.csv")
    m = HybridModel(rob, calibrate=False, recipe_kw={"max_epochs": 1}, uncertainty=False).fit(ds, progress=False)
    m.save(d / "m.hykin")
    (d / "m_as.toml").write_bytes((d / "m.hykin").read_bytes())
    with open(d / "joints.csv", "w") as f:
        f.write("q1,q2,q3,q4,q5,q6\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in ds.q[:5]) + "\n")
    return d


def test_fit_refuses_an_output_the_other_commands_read_as_data(tiny_model, capsys):
    d = tiny_model
    for name in ("model.csv", "model.toml"):
        code, _, err = run(["fit", "rx160", d / "train.csv", "-o", d / name, "--max-epochs", "1"], capsys)
        assert code == 2 and err.count("\n") == 1 and name in err and "name it .hykin" in err, err
        assert not (d / name).exists()


def test_a_model_file_given_as_robot_is_named(tiny_model, capsys):
    d = tiny_model
    code, _, err = run(["fit", d / "m.hykin", d / "train.csv", "-o", d / "x.hykin"], capsys)
    assert code == 2 and err.count("\n") == 1 and "m.hykin: this is a hykin model file" in err and "utf-8" not in err
    code, _, err = run(["fk", d / "m_as.toml", d / "joints.csv", "-o", d / "o.csv"], capsys)
    assert code == 2 and "m_as.toml: this is a hykin model file" in err and "rename it .hykin" in err, err


def test_payload_without_compliance_warns_in_one_line(tiny_model, capsys):
    d = tiny_model
    code, _, err = run(["fk", d / "m.hykin", d / "joints.csv", "-o", d / "p.csv", "--payload-kg", "20"], capsys)
    assert code == 0 and "--payload-kg 20: the model's robot has no joint stiffness" in err
    code, _, err = run(["fk", "rx160", d / "joints.csv", "-o", d / "p2.csv", "--payload-kg", "20"], capsys)
    assert code == 0 and "robot 'rx160' has no joint stiffness" in err
    from hykin.io.robot_toml import save_robot_toml

    stiff = load_robot("rx160").copy(stiffness_nm_per_rad=np.full(6, 1e5))
    save_robot_toml(stiff, d / "stiff.toml")
    code, _, err = run(["fk", d / "stiff.toml", d / "joints.csv", "-o", d / "p3.csv", "--payload-kg", "20"], capsys)
    assert code == 0 and "stiffness" not in err, err


def test_fk_accepts_joints_a_hair_past_a_limit(tiny_model, capsys):
    from hykin.io.dataset import JointLimitWarning

    d = tiny_model
    rob = load_robot("rx160")
    q = np.zeros((2, 6))
    q[1, 1] = np.degrees(rob.upper[1]) + 0.001
    with open(d / "lim.csv", "w") as f:
        f.write("q1,q2,q3,q4,q5,q6\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in q) + "\n")
    with pytest.warns(JointLimitWarning, match=r"1 of 2 rows have joints slightly beyond the limits .*\(q2: 1;"):
        code, out, err = run(["fk", "rx160", d / "lim.csv", "-o", d / "lim_out.csv", "--angle-unit", "deg"], capsys)
    assert code == 0, err
    T = fk(rob, np.radians(q))
    header = (d / "lim_out.csv").read_text().splitlines()[0].split(",")
    rows = np.loadtxt(d / "lim_out.csv", delimiter=",", skiprows=1)
    xyz = rows[:, [header.index(c) for c in ("x", "y", "z")]]
    np.testing.assert_allclose(xyz, T[:, :3, 3], atol=1e-12)
