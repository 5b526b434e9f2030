"""The generated battery (issue #24): random robots and measurement campaigns through the CLI.

Property: for every draw, ``hykin fit ROBOT train.csv -o model.hykin`` then ``hykin evaluate model.hykin
test.csv --json`` (files on disk, in-process CLI) either gives a model whose held-out mean position
error is within ``FLOOR_FACTOR`` (1.5) × the truth's noise floor + 0.01 mm, or refuses with one line
naming the cause; a correct input is never refused (:mod:`hykin.sim.battery`).

* generator checks (default suite): the files describe the drawn robots (TOML in every unit, URDF
  with fixed joints and branches read back by hykin's readers give the same FK), mimic joints follow
  their leaders, the truth is off by what was drawn, the noise floor is the noise, campaigns are
  reproducible from their seed;
* a fast slice (default suite): a few draws of the families that pass on main;
* a slow slice (``-m slow``): ``HYKIN_BATTERY_DRAWS`` (default 500) draws over the same families;
  and the families that fail on main today (:data:`KNOWN_FAILING`, each with the branch that fixes
  it) as non-strict xfail, so they show up as XPASS once fixed.

A failing draw prints its family, seed, cause and the command lines that reproduce it.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

from hykin.geometry import se3
from hykin.io.robot_toml import robot_from_toml_text
from hykin.io.urdf import load_urdf_string
from hykin.kinematics.fk import fk
from hykin.kinematics.robot import robot_reach_m
from hykin.sim.battery import run_campaign
from hykin.sim.random_campaigns import FAMILIES, draw_campaign
from hykin.sim.random_robots import draw_robot

from cli_run import run_captured

# the model's own out-of-range warning is expected here: the queries are random joints
pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")

# Families that pass on main (benchmarks/bench_battery.py --draws 520 --seed 1000: 20 draws each; two
# rare failures remain that the slow slice can meet: "tracker" 1/20 (a 4-joint arm whose tool offset
# walks to 2.2 m: calibration priors). "slip-xyzw" seed 1004 (a planar arm, where the misread rotations
# pass the pre-fit quaternion-order check) used to fit at 2.4 mm, 55x the noise floor, without a word;
# it is now refused by the orientation-conflict bound (test_slip_xyzw_planar_arm_refused).
PASSING = ["dh", "mdh", "prismatic", "data-units", "tracker", "position-only", "reflectors3", "noise", "payload",
           "thermal", "subregion", "few-poses", "urdf", "sweeps", "wrong-swap", "wrong-length", "slip-mm",
           "slip-deg", "slip-xyzw", "slip-file-mm", "slip-file-deg", "urdf-prismatic",
           # failed before issue #24's branches; each passed 3 of 3 seeds on 2026-11-27 (test_battery_known_failing
           # XPASS): "tracker-far" (positions over 10 m), "urdf-mimic", "urdf-two-tips" (--tip), "constant-orientation"
           # (calibration priors), "stations"
           "tracker-far", "urdf-mimic", "urdf-two-tips", "constant-orientation", "stations"]
# Families that fail on main today, and the branch that addresses them (none at present).
KNOWN_FAILING: dict[str, str] = {}
FAST = ["tracker", "dh", "mdh", "position-only", "urdf", "slip-mm", "slip-deg", "slip-xyzw", "slip-file-mm", "slip-file-deg"]
SLOW_DRAWS = int(os.environ.get("HYKIN_BATTERY_DRAWS", "500"))

seeds = st.integers(min_value=0, max_value=100_000)


def _check(family: str, seed: int, folder) -> None:
    v = run_campaign(draw_campaign(family, seed), folder, run_captured)
    assert v.ok, f"{v.summary()}\nreproduce:\n{v.reproduce()}"


# --------------------------------------------------------------------------- generators


def _fk_err_m(a, b, q) -> float:
    return float(np.abs(fk(a, q)[:, :3, 3] - fk(b, q)[:, :3, 3]).max())


@settings(max_examples=12)
@given(seed=seeds, kind=st.sampled_from(["dh", "mdh"]), lu=st.sampled_from(["m", "mm"]), au=st.sampled_from(["deg", "rad"]))
def test_toml_files_describe_the_drawn_robot_in_every_unit(seed, kind, lu, au):
    rng = np.random.default_rng(seed)
    rr = draw_robot(rng, kind, units=(lu, au), prismatic=bool(seed % 3 == 0), masses=bool(seed % 2))
    assert f'length_unit = "{lu}"' in rr.file_text and f'angle_unit = "{au}"' in rr.file_text
    read = robot_from_toml_text(rr.file_text, "drawn.toml")
    q = rr.random_joints(20, rng)
    assert read.dof == rr.dof and 4 <= rr.dof <= 7
    assert _fk_err_m(read, rr.nominal, q) < 1e-9
    np.testing.assert_allclose(read.mass_kg, rr.nominal.mass_kg)
    # link lengths 0.05-1.2 m, a realistic arm
    lengths = np.concatenate([np.abs(rr.nominal.a_m), np.abs(rr.nominal.d_m)])
    assert np.all((lengths == 0) | ((lengths > 0.01) & (lengths <= 1.2)))


@settings(max_examples=10)
@given(seed=seeds, two_tips=st.booleans(), column=st.booleans())
def test_urdf_files_describe_the_drawn_robot(seed, two_tips, column):
    """Fixed joints, dead-end branches, rpy origins, a prismatic column: hykin's URDF reader (naming
    the tip where there are two) gives the FK of the chain the generator built."""
    rng = np.random.default_rng(seed)
    rr = draw_robot(rng, "urdf", two_tips=two_tips, column=column)
    assert (rr.nominal.joint_type[0] == "prismatic") == column
    assert (rr.tip is not None) == two_tips
    read = load_urdf_string(rr.file_text, tip_link=rr.tip)
    q = rr.random_joints(20, rng)
    assert _fk_err_m(read, rr.nominal, q) < 1e-9
    if two_tips:
        with pytest.raises(ValueError, match="name tip_link"):
            load_urdf_string(rr.file_text)


@settings(max_examples=15)
@given(seed=seeds, n_mimic=st.integers(1, 2))
def test_mimic_joints_follow_their_leader(seed, n_mimic):
    rng = np.random.default_rng(seed)
    rr = draw_robot(rng, "urdf", dof=6, n_mimic=n_mimic)
    assert rr.file_text.count("<mimic ") == n_mimic
    assert rr.nominal.dof == rr.dof + n_mimic
    q = rr.random_joints(30, rng, margin=0.0)
    qa = rr.full_joints(q)
    assert rr.nominal.within_limits(qa).all()
    lead = qa[:, 0]  # the column joint leads; its stages follow: q = m * q_lead + c
    for r in range(1, 1 + n_mimic):
        m = np.polyfit(lead, qa[:, r], 1)
        assert 0.5 <= m[0] <= 1.0 and abs(m[1]) <= 0.02
        np.testing.assert_allclose(qa[:, r], np.polyval(m, lead), atol=1e-12)
    np.testing.assert_array_equal(qa[:, 1 + n_mimic:], q[:, 1:])


@settings(max_examples=20)
@given(seed=seeds, kind=st.sampled_from(["dh", "mdh", "urdf"]))
@example(seed=18352, kind="urdf")  # σ 2 mm / 0.2° on a long 7-link arm: 31 mm on average
def test_truth_is_off_by_what_was_drawn(seed, kind):
    """The truth's TCP differs from the file's by about the drawn σ times the lever arms: the scale
    sqrt(frames) (σ_m + σ_rad · reach) between 0.1 and 5 times it (0.17-1.8 over 400 draws of each
    kind), and always more than the noise (0.01 mm)."""
    rng = np.random.default_rng(seed)
    rr = draw_robot(rng, kind)
    q = rr.full_joints(rr.random_joints(50, rng))
    d = np.linalg.norm(fk(rr.truth, q)[:, :3, 3] - fk(rr.nominal, q)[:, :3, 3], axis=1)
    scale = math.sqrt(rr.nominal.dof + 2) * (rr.sigma_m + rr.sigma_rad * robot_reach_m(rr.nominal))
    assert 1e-5 < d.mean() and 0.1 * scale < d.mean() < 5 * scale


@settings(max_examples=12)
@given(seed=seeds, family=st.sampled_from(list(FAMILIES)))
def test_campaigns_are_reproducible_and_floor_is_the_noise(seed, family):
    a, b = draw_campaign(family, seed), draw_campaign(family, seed)
    np.testing.assert_array_equal(a.train.q, b.train.q)
    np.testing.assert_array_equal(a.test.xyz_m, b.test.xyz_m)
    assert a.robot.file_text == b.robot.file_text and a.robot_text == b.robot_text
    assert a.train.q.shape[1] == a.robot.dof
    if a.expect == "model":
        # 3-D Gaussian noise σ per axis: mean norm σ·sqrt(8/π); 40 held-out rows, noise σ 0.005-0.2 mm
        assert 0.005 * 0.5 < a.floor_mm < 0.2 * 1.6 * 1.6


def test_special_campaigns_measure_what_they_say():
    c = draw_campaign("constant-orientation", 3)
    R = se3.quat_to_matrix(c.train.quat_wxyz)
    spread = np.degrees(np.linalg.norm(se3.rotation_difference_rotvec(R, R[:1]), axis=1)).max()
    assert spread < 0.1  # the tool held at one orientation (measurement noise only)
    s = draw_campaign("stations", 3)
    assert len(set(s.train.extra["station"])) >= 2
    w = draw_campaign("sweeps", 3)
    moved = np.count_nonzero(np.diff(w.train.q, axis=0), axis=1)
    assert np.all(moved <= 2)  # from one sweep pose to the next at most two joints change
    far = draw_campaign("tracker-far", 3)
    assert np.linalg.norm(far.train.xyz_m, axis=1).min() > 7.0
    t = draw_campaign("thermal", 3)
    assert np.ptp(t.train.extra["temperature_c"]) > 2.0


# --------------------------------------------------------------------------- the CLI property


@settings(max_examples=1, phases=[Phase.explicit, Phase.generate], suppress_health_check=[HealthCheck.too_slow])
@given(family=st.sampled_from(FAST), seed=seeds)
@example(family="tracker", seed=1)
@example(family="position-only", seed=3)
@example(family="slip-xyzw", seed=4)
@example(family="slip-file-deg", seed=5)
def test_battery_fast_slice(family, seed, tmp_path_factory):
    _check(family, seed, tmp_path_factory.mktemp(f"battery-{family}-{seed}"))


@pytest.mark.slow
def test_slip_xyzw_planar_arm_refused(tmp_path):
    """The draw that fitted silently: a 4-joint arm with parallel axes, quaternions scalar-last. The
    6-D calibration leaves 2.7 mm RMS where the positions alone leave 0.042 mm: refused, one line
    naming the file, its qw..qz columns and the scalar-last order (hykin.calibration.consistency)."""
    v = run_campaign(draw_campaign("slip-xyzw", 1004), tmp_path, run_captured)
    assert v.ok and v.outcome == "refused", f"{v.summary()}\nreproduce:\n{v.reproduce()}"
    assert "train.csv: columns qw,qx,qy,qz" in v.line and "scalar-last" in v.line, v.line


@pytest.mark.slow
def test_battery_slow_slice(tmp_path_factory):
    """``SLOW_DRAWS`` draws over the families that pass on main; every draw runs, and the failures are
    reported together (family, seed, cause, command lines), as the benchmark does."""
    failures = []

    @settings(max_examples=SLOW_DRAWS, phases=[Phase.generate], suppress_health_check=list(HealthCheck))
    @given(family=st.sampled_from(PASSING), seed=seeds)
    def draw(family, seed):
        v = run_campaign(draw_campaign(family, seed), tmp_path_factory.mktemp(f"battery-{family}-{seed}"), run_captured)
        if not v.ok:
            failures.append(v)

    draw()
    assert not failures, f"{len(failures)} of {SLOW_DRAWS} draws failed:\n" + "\n".join(
        f"{v.summary()}\n{v.reproduce()}" for v in failures)


@pytest.mark.slow
@pytest.mark.parametrize("family", sorted(KNOWN_FAILING))
@pytest.mark.xfail(strict=False, reason="fails on main today; see KNOWN_FAILING")
def test_battery_known_failing(family, tmp_path):
    for seed in range(3):
        _check(family, seed, tmp_path / str(seed))


def test_family_lists_cover_every_family():
    assert sorted(PASSING + list(KNOWN_FAILING)) == sorted(FAMILIES)
    assert set(FAST) <= set(PASSING)
    assert not math.isnan(SLOW_DRAWS)
