"""Refusal texts of robot loading and model queries: a URDF written in mm, a wrong ``--tip`` name, and
the support report of ``hykin ik`` (an empty list once printed "(; in holes ...)")."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from cli_run import run
from hykin.hybrid.support import support_report
from hykin.io.urdf import MAX_CHAIN_LENGTH_M, load_urdf, load_urdf_string
from hykin.kinematics.fk import fk
from hykin.kinematics.robot import RobotFileError

URDF = Path(__file__).parent / "data" / "construction_robot.urdf"


def _scaled(text: str, k: float) -> str:
    """Every ``<origin xyz>`` of the URDF times ``k`` (what a URDF written in mm looks like for k = 1000)."""
    root = ET.fromstring(text)
    for o in root.iter("origin"):
        if o.get("xyz"):
            o.set("xyz", " ".join(f"{float(v) * k:.12g}" for v in o.get("xyz").split()))
    return ET.tostring(root, encoding="unicode")


def _arm_origins(text: str, tip: str) -> dict[str, float]:
    """Independent of hykin: the origin lengths of the joints from the first movable one (excluded) to ``tip``."""
    root = ET.fromstring(text)
    by_child = {j.find("child").get("link"): j for j in root.iter("joint")}
    chain, ln = [], tip
    while ln in by_child:
        chain.append(by_child[ln])
        ln = by_child[ln].find("parent").get("link")
    chain = chain[::-1]
    first = next(i for i, j in enumerate(chain) if j.get("type") != "fixed")
    out = {}
    for j in chain[first + 1:]:
        o = j.find("origin")
        out[j.get("name")] = 0.0 if o is None else float(np.linalg.norm([float(v) for v in o.get("xyz", "0 0 0").split()]))
    return out


def test_urdf_in_mm_is_refused_naming_the_joint(tmp_path, capsys):
    text = URDF.read_text()
    lengths = _arm_origins(text, "tcp")
    worst = max(lengths, key=lengths.get)
    mm = tmp_path / "robot_mm.urdf"
    mm.write_text(_scaled(text, 1000.0))
    with pytest.raises(RobotFileError) as e:
        load_urdf(mm, tip_link="tcp")
    msg = str(e.value)
    assert str(mm) in msg and f"joint '{worst}'" in msg and "lengths look like mm (URDF uses metres)" in msg
    total = float(re.search(r"add up to ([\d.e+]+) m", msg).group(1))
    assert total == pytest.approx(1000.0 * sum(lengths.values()), rel=1e-3)
    # through the command line: one line, exit 2, nothing written
    q = tmp_path / "q.csv"
    q.write_text("q1,q2,q3,q4,q5,q6,q7\n" + ",".join(["0.1"] * 7) + "\n")
    code, so, se = run(["fk", mm, q, "--tip", "tcp", "-o", tmp_path / "x.csv"], capsys)
    assert code == 2 and len(se.strip().splitlines()) == 1 and "look like mm" in se and not (tmp_path / "x.csv").exists()


def test_long_chain_in_metres_is_accepted_and_the_placement_is_not_counted():
    text = URDF.read_text()
    total = sum(_arm_origins(text, "tcp").values())
    k = 0.9 * MAX_CHAIN_LENGTH_M / total  # a very long (but possible) machine: accepted
    r = load_urdf_string(_scaled(text, k), tip_link="tcp")
    assert r.dof == 7
    # a robot placed 500 m from the cell's origin is no arm of 500 m
    root = ET.fromstring(text)
    for j in root.iter("joint"):
        if j.find("parent").get("link") == "world":
            x0, y0, z0 = (float(v) for v in j.find("origin").get("xyz").split())
            j.find("origin").set("xyz", f"{x0 + 500} {y0} {z0}")
    far = load_urdf_string(ET.tostring(root, encoding="unicode"), tip_link="tcp")
    q = far.random_joints(5, rng=1)
    d = fk(far, q)[:, :3, 3] - fk(load_urdf(URDF, tip_link="tcp"), q)[:, :3, 3]
    np.testing.assert_allclose(d, np.tile([500.0, 0, 0], (5, 1)), atol=1e-9)
    with pytest.raises(RobotFileError, match="look like mm"):
        load_urdf_string(_scaled(text, 1.1 * MAX_CHAIN_LENGTH_M / total), tip_link="tcp")


def test_wrong_tip_lists_the_tips():
    with pytest.raises(RobotFileError) as e:
        load_urdf(URDF, tip_link="tool1")
    msg = str(e.value)
    assert "tip_link 'tool1' is not a link" in msg
    tips = msg.split("are: ")[1].split(" (")[0].split(", ")
    assert tips == ["camera_link", "tcp"]  # the several-tips refusal's list (laser_frame is a dead end)
    with pytest.raises(RobotFileError, match=r"several tips \(camera_link, tcp\)"):
        load_urdf(URDF)


class _Fake:
    """A model with given range excess ``(N, n)`` and support distance ``(N,)``."""

    def __init__(self, ex, d):
        self.ex, self.d = np.asarray(ex, float), np.asarray(d, float)

    def range_excess(self, q):
        return self.ex

    def support_distance(self, q):
        return self.d


@pytest.mark.parametrize("ex, d, inner", [
    ([[0, 0], [0, 0], [0, 0]], [0.0, 0.3, 0.0], "(in holes of the training data: 1)"),
    ([[0.2, 0], [0, 0], [0, 0.1]], [0.2, 0.0, 0.1], "(outside the trained joint range: q1: 1, q2: 1)"),
    ([[0.2, 0], [0, 0], [0, 0]], [0.2, 0.4, 0.0], "(outside the trained joint range: q1: 1; in holes of the training data: 1)"),
])
def test_support_report_text(ex, d, inner):
    r = support_report(_Fake(ex, d), np.zeros((3, 2)))
    n_out = sum(1 for e, x in zip(ex, d) if max(e) > 0 or x > 0)
    assert r["outside"] == n_out
    assert r["message"] == (f"{n_out} of 3 queries lie outside the training region of the networks {inner}; "
                            "the correction fades to the calibrated model there")
    assert "(;" not in r["message"] and "()" not in r["message"]
    assert support_report(_Fake(np.zeros((3, 2)), np.zeros(3)), np.zeros((3, 2)))["message"] == ""
