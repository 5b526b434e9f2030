"""The report's calibration table against the calibration itself (issue #27): for a DH robot and for
URDF robots with and without <mimic>, a hybrid model is fitted (calibration with priors), saved and
reloaded as a user's file, and the report built from it. Every parameter of the
:class:`hykin.calibration.result.CalibrationResult` has one row whose status cell is the result's
status (a correlated one naming its partners), whose deviation / posterior std / prior std are the
result's in the shown unit, and whose nominal and identified values are read here from the robots'
own fields (DH arrays, URDF joint origins), not through the report's code."""

from __future__ import annotations

import html as html_mod
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from hykin.calibration.params import apply_deviations, parameter_names
from hykin.geometry import se3
from hykin.io.dataset import Dataset
from hykin.io.urdf import load_urdf
from hykin.kinematics.fk import fk

DATA = Path(__file__).parent / "data"
SCALE = {"m": 1e3, "rad": 180 / math.pi, "c": 1e6}


def _data(nom, truth, n, seed, q_fixed=None) -> Dataset:
    """Noisy full poses of ``truth`` at random joints of ``nom`` (joints in ``q_fixed`` held: index -> rad)."""
    rng = np.random.default_rng(seed)
    q = nom.random_joints(n, rng=rng, margin=0.05)
    for j, v in (q_fixed or {}).items():
        q[:, j] = v
    T = fk(truth, q)
    quat = se3.matrix_to_quat(T[:, :3, :3])
    return Dataset(q=q, xyz_m=T[:, :3, 3] + rng.normal(0, 2e-5, (n, 3)), quat_wxyz=quat, source=f"simulated seed {seed}")


def _fit_and_report(nom, truth, tmp_path, q_fixed=None):
    from hykin.evaluation.report_build import build_report
    from hykin.hybrid.model import HybridModel

    train = _data(nom, truth, 400, 1, q_fixed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = HybridModel(nom, seed=0, recipe_kw={"max_epochs": 1, "min_steps": 20}, val_fraction=0.1,
                        uncertainty=False).fit(train, progress=False)  # bands: not what this test reads
    res = m.calibration
    m.save(tmp_path / "m.hykin")
    loaded = HybridModel.load(tmp_path / "m.hykin")  # the report of a user's model file (no CalibrationResult)
    rep, _ = build_report(loaded, None, model_path=tmp_path / "m.hykin", ik_targets=0)
    return res, _table(rep.html())


def _table(page: str) -> dict[str, dict[str, str]]:
    """The calibration table of a report page: parameter -> {column header: cell text}."""
    for tab in re.findall(r"<table>.*?</table>", page, flags=re.S):
        head = [html_mod.unescape(h) for h in re.findall(r"<th[^>]*>(.*?)</th>", tab)]
        if "posterior std" in head and "status" in head:
            rows = {}
            for tr in re.findall(r"<tr[^>]*>(.*?)</tr>", tab.split("<tbody>")[1]):
                cells = [html_mod.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", tr)]
                rows[cells[0]] = dict(zip(head, cells))
            return rows
    raise AssertionError("no calibration table in the report")


def _num(cell: str) -> float | None:
    return None if cell.strip() in ("", "–", "-", "None") else float(cell)


def _close(cell: str, ref: float | None, name: str, col: str) -> None:
    got = _num(cell)
    if ref is None or not np.isfinite(ref):
        assert got is None, (name, col, cell)
    else:
        assert got == pytest.approx(ref, rel=2e-5, abs=1e-9), (name, col, cell, ref)


def _check(res, table, nominal_of, identified_of) -> set[str]:
    """Every parameter's row against ``res``; returns the statuses seen."""
    assert set(table) == set(res.names)
    for i, name in enumerate(res.names):
        row, st, f = table[name], res.status[i], SCALE[res.units[i]]
        if st == "correlated":
            partners = res.correlated_with[i]
            assert partners and row["status"].startswith("correlated with "), (name, row["status"])
            for other, rho in partners:
                assert f"{other} (ρ {rho:+.3f})" in row["status"], (name, row["status"])
        else:
            assert row["status"] == st, (name, row["status"], st)
        assert ("held" in st) == ("held" in row["status"])
        _close(row["deviation"], res.values[i] * f if res.identifiable[i] else 0.0, name, "deviation")
        _close(row["posterior std"], res.std[i] * f, name, "posterior std")
        _close(row["prior std"], res.prior_std[i] * f, name, "prior std")
        if not name.startswith(("base.", "tool.", "beta")):
            _close(row["nominal"], nominal_of(name) * f, name, "nominal")
            _close(row["identified"], identified_of(name) * f, name, "identified")
    return set(res.status)


def _dh_value(robot, name: str) -> float:
    m = re.fullmatch(r"(a|alpha|d|theta|c)(\d+)", name)
    field, j = m.group(1), int(m.group(2)) - 1
    if field == "c":
        return 1.0 / robot.stiffness_nm_per_rad[j] if robot.stiffness_nm_per_rad is not None and np.isfinite(
            robot.stiffness_nm_per_rad[j]) and robot.stiffness_nm_per_rad[j] > 0 else 0.0
    return float({"a": robot.a_m, "alpha": robot.alpha_rad, "d": robot.d_m, "theta": robot.theta_rad}[field][j])


def _urdf_value(robot, name: str) -> float:
    m = re.fullmatch(r"o(\d+)\.(x|y|z|rx|ry|rz)|c(\d+)", name)
    if m.group(3):
        k = int(m.group(3)) - 1
        s = robot.stiffness_nm_per_rad
        return 1.0 / s[k] if s is not None and np.isfinite(s[k]) and s[k] > 0 else 0.0
    j, k = int(m.group(1)) - 1, ("x", "y", "z", "rx", "ry", "rz").index(m.group(2))
    return float(robot.origin_xyz_m[j][k] if k < 3 else robot.origin_rpy_rad[j][k - 3])


def test_dh_report_table_is_the_calibration(tmp_path):
    """rx160 (DH) with joint 6 never moved: theta6 and the tool's rotation about the flange axis are
    not separable, so the table must show held / correlated rows as the calibration states them."""
    from hykin.io.robot_file import load_robot

    nom = load_robot("rx160")
    dev = {"a2": 4e-4, "d4": -3e-4, "theta2": 2e-4, "alpha3": -1e-4, "theta3": 3e-4}
    truth = apply_deviations(nom, dev)
    truth = truth.copy(tool=truth.tool @ se3.xyzrpy_to_transform([0.002, -0.001, 0.003], [0.0, 0.0, 0.0]))
    res, table = _fit_and_report(nom, truth, tmp_path, q_fixed={5: 0.3})
    seen = _check(res, table, lambda n: _dh_value(nom, n), lambda n: _dh_value(res.robot, n))
    assert "identified" in seen and len(seen) >= 2, seen  # not only one kind of status
    assert table["a2"]["deviation"] and float(table["a2"]["deviation"]) == pytest.approx(0.4, abs=0.02)


@pytest.mark.parametrize("urdf, tip", [
    pytest.param("test_arm.urdf", None, id="urdf", marks=pytest.mark.slow),  # the mimic case covers URDF origins too
    pytest.param("construction_robot.urdf", "tcp", id="urdf-mimic")])
def test_urdf_report_table_is_the_calibration(tmp_path, urdf, tip):
    nom = load_urdf(DATA / urdf, tip_link=tip)
    rng = np.random.default_rng(3)
    names = parameter_names(nom, base=False, tool=False, compliance=False)
    truth = apply_deviations(nom, {n: rng.normal(0, 3e-4) for n in names})
    res, table = _fit_and_report(nom, truth, tmp_path)
    seen = _check(res, table, lambda n: _urdf_value(nom, n), lambda n: _urdf_value(res.robot, n))
    assert "identified" in seen, seen
    if tip:  # the mimic stages: origins of the two mimic joints are rows too
        assert nom.dof == 7 and {"o8.x", "o9.x"} <= set(table)
