"""Random measurement campaigns of random robots: what a user measures, as files on disk.

:func:`draw_campaign` ``(family, seed)`` draws a robot (:mod:`hykin.sim.random_robots`), a way of
measuring it (tracker frame metres to kilometres away and turned, several stations, constant tool
orientation, single-axis sweeps, a joint sub-region, few poses, position-only / three reflectors /
6-D, noise, payloads, thermal drift) and, for the "mistake" families, what the user got wrong (a
wrong robot file, a unit slip). The :class:`Campaign` holds the training and held-out data, the
command-line options a user would pass, and what hykin must do with it:

* ``expect == "model"``: a correct input. hykin must return a model whose held-out mean position
  error is within ``FLOOR_FACTOR × floor_mm + FLOOR_SLACK_MM`` (:func:`hykin.sim.battery.judge`);
  ``floor_mm`` is the truth's noise floor on the held-out poses: the mean distance between the
  measured and the true (noise-free) positions, i.e. the error of a perfect model.
* ``expect == "refuse"``: a user mistake. hykin must exit non-zero with one line containing one of
  ``causes`` (lower-case keywords naming the cause: units, robot file, ...).
* ``expect == "model-or-refuse"``: either is right (a robot file off by centimetres may be
  calibrated to the truth or refused naming it; a few poses may be refused as too few).

Everything is drawn from ``numpy.random.default_rng([seed, family_index])``: same family and seed,
same files. :data:`FAMILIES` lists the families with a one-line description.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import se3
from ..io.dataset import Dataset
from ..io.dataset_files import write_dataset
from ..io.plausibility import minimum_fit_rows
from ..io.robot_toml import robot_to_toml_string
from ..kinematics.fk import fk
from .random_robots import RandomRobot, draw_robot
from .simulate import ThermalDrift, VirtualRobot, simulate, true_poses

__all__ = ["FAMILIES", "Campaign", "draw_campaign"]

_DEG = math.pi / 180

FAMILIES: dict[str, str] = {
    "dh": "standard-DH arm (file in m/mm, deg/rad), 6-D data in the robot base frame",
    "mdh": "modified-DH arm (file in m/mm, deg/rad), 6-D data in the robot base frame",
    "prismatic": "DH arm on a linear column (prismatic joint 1), 6-D data",
    "data-units": "data written in mm and degrees, declared with --length-unit mm --angle-unit deg",
    "tracker": "tracker frame 1-6 m away and turned, robot file without [base], 6-D",
    "tracker-far": "tracker frame 10 m to 2 km away and turned, 6-D",
    "position-only": "tracker frame 1-6 m away, positions only (one reflector)",
    "reflectors3": "tracker frame 1-6 m away, three reflectors (x,y,z, x2..z3), no orientation",
    "noise": "measurement noise 0.005-0.2 mm / 0.001-0.02 deg",
    "payload": "file with masses and stiffness, compliant truth, 2-3 payloads (payload_kg column)",
    "thermal": "steel/aluminium arm warming up 4-10 K (temperature_c column)",
    "subregion": "data only in a sub-region of joint space (30 % of each range)",
    "few-poses": "1-1.5x the minimum number of poses hykin accepts",
    "urdf": "maker-style URDF: rpy origins, fixed joints, dead-end branches, 6-D",
    "urdf-mimic": "URDF with a lifting column driving 1-2 <mimic> stages, data with independent joints",
    "urdf-two-tips": "URDF with two TCPs (tool0, tool1); the user names --tip tool0",
    "constant-orientation": "tool held at one orientation (6-D), positions in a 0.16-0.6 m box",
    "sweeps": "single-axis sweeps from a home pose (one joint moves per pose)",
    "stations": "2-3 stations 3 m from the robot, 5-7 m apart, a station column, one frame per station",
    "wrong-swap": "robot file with two consecutive joints swapped",
    "wrong-length": "robot file with one link length off by 2-10 cm",
    "slip-mm": "positions written in mm, no --length-unit",
    "slip-deg": "joints written in degrees, no --angle-unit",
    "slip-xyzw": "quaternions written scalar-last (x,y,z,w) under the qw,qx,qy,qz header",
    "slip-file-mm": "robot file in mm that says length_unit = \"m\"",
    "slip-file-deg": "robot file in degrees that says angle_unit = \"rad\"",
    "urdf-prismatic": "URDF of an arm on a lifting column (prismatic joint 1, no mimic), 6-D",
}

_UNIT_CAUSES = ("mm", "millimet", "length-unit", "length unit", "length_unit", "unit")


@dataclass
class Campaign:
    """One drawn campaign (see module docstring). ``train`` / ``test``: datasets as they go on disk
    (after any unit slip; columns in SI unless ``write_units`` says otherwise). ``fit_args`` /
    ``eval_args``: options a user passes to ``hykin fit`` / ``hykin evaluate``. ``floor_mm``: mean
    |measured - true| position on the held-out rows (mm)."""

    family: str
    seed: int
    robot: RandomRobot
    train: Dataset
    test: Dataset
    expect: str
    causes: tuple[str, ...] = ()
    fit_args: list[str] = field(default_factory=list)
    eval_args: list[str] = field(default_factory=list)
    floor_mm: float = 0.0
    write_units: tuple[str, str] = ("m", "rad")
    robot_text: str | None = None
    describe: str = ""

    def write(self, folder) -> dict[str, Path]:
        """Write the robot file, ``train.csv`` and ``test.csv`` into ``folder``; returns their paths."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        robot = folder / f"robot{self.robot.suffix}"
        robot.write_text(self.robot_text if self.robot_text is not None else self.robot.file_text, encoding="utf-8")
        paths = {"robot": robot, "train": folder / "train.csv", "test": folder / "test.csv"}
        lu, au = self.write_units
        write_dataset(self.train, paths["train"], length_unit=lu, angle_unit=au)
        write_dataset(self.test, paths["test"], length_unit=lu, angle_unit=au)
        return paths


# --------------------------------------------------------------------------- measuring


def _random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return se3.quat_to_matrix(q / np.linalg.norm(q))


def _tracker_frame(rng, lo_m: float, hi_m: float) -> np.ndarray:
    """Tracker (world) -> robot base: the robot ``lo_m``-``hi_m`` from the instrument, turned any way."""
    d = rng.normal(size=3)
    return se3.make_transform(_random_rotation(rng), d / np.linalg.norm(d) * rng.uniform(lo_m, hi_m))


def _measure(rr: RandomRobot, q_ind, rng, *, frame=None, noise_m=20e-6, noise_rad=0.002 * _DEG, thermal=None,
             temperature=None, payload_kg=None, reflectors=None, orientation=True) -> tuple[Dataset, np.ndarray]:
    """Simulated measurements at independent joints ``q_ind`` and the true TCP positions ``(N, 3)``."""
    truth = rr.truth if frame is None else rr.truth.copy(base=frame @ rr.truth.base)
    vr = VirtualRobot(name="battery", nominal=rr.nominal, truth=truth, thermal=thermal, noise_position_m=noise_m,
                      noise_orientation_rad=noise_rad)
    q_all = rr.full_joints(q_ind)
    kw = {} if payload_kg is None else {"payload_kg": payload_kg}
    ds = simulate(vr, q_all, rng=rng, temperature=temperature, **kw)
    T = true_poses(vr, q_all, temperature_c=temperature, **kw)
    ds.q = np.array(q_ind, dtype=np.float64)
    if reflectors is not None:  # further reflectors on the tool body: offsets (K, 3) in the TCP frame
        for k, off in enumerate(reflectors, start=2):
            p = T[:, :3, :3] @ off + T[:, :3, 3] + rng.normal(0, noise_m, (len(T), 3))
            for c, col in enumerate("xyz"):
                ds.extra[f"{col}{k}"] = p[:, c]
    if not orientation:
        ds.quat_wxyz = None
    ds.extra.pop("sample", None)
    return ds, T[:, :3, 3]


def _split(ds: Dataset, n_train: int) -> tuple[Dataset, Dataset]:
    def rows(sl):
        return Dataset(q=ds.q[sl], xyz_m=ds.xyz_m[sl], quat_wxyz=None if ds.quat_wxyz is None else ds.quat_wxyz[sl],
                       extra={k: np.asarray(v)[sl] for k, v in ds.extra.items()}, source=ds.source)

    return rows(slice(0, n_train)), rows(slice(n_train, None))


def _constant_orientation_joints(rr: RandomRobot, n: int, rng) -> np.ndarray:
    """Joints reaching positions in a box (0.16-0.6 m) around a random pose, all at that pose's true
    orientation (IK on the truth: the tool orientation is constant up to the measurement noise)."""
    from ..kinematics.ik import ik_numeric

    for _ in range(10):
        q0 = rr.random_joints(1, rng, margin=0.25)
        T0 = fk(rr.truth, q0)[0]
        for box in (0.3, 0.15, 0.08):
            T = np.repeat(T0[None], 3 * n, axis=0)
            T[:, :3, 3] += rng.uniform(-box, box, (3 * n, 3))
            res = ik_numeric(rr.truth, T, q_seed=q0[0], tol_m=1e-8, tol_rad=1e-8, restarts=0, rng=rng)
            ok = np.flatnonzero(res.success)
            if ok.size >= n:
                return res.q[ok[:n]]
    raise RuntimeError("constant-orientation campaign: no reachable box found")


def _sweep_joints(rr: RandomRobot, n: int, rng) -> np.ndarray:
    """Single-axis sweeps: from one home pose, pose i moves joint ``i mod dof`` only."""
    home = rr.random_joints(1, rng, margin=0.3)[0]
    q = np.repeat(home[None], n, axis=0)
    span = rr.upper - rr.lower
    for i in range(n):
        j = i % rr.dof
        q[i, j] = rng.uniform(rr.lower[j] + 0.05 * span[j], rr.upper[j] - 0.05 * span[j])
    return q


def _floor_mm(test: Dataset, p_true: np.ndarray) -> float:
    return float(np.linalg.norm(test.xyz_m - p_true, axis=1).mean() * 1e3)


# --------------------------------------------------------------------------- families


def _family_robot(family: str, rng) -> RandomRobot:
    if family == "mdh":
        return draw_robot(rng, "mdh")
    if family == "prismatic":
        return draw_robot(rng, "dh", prismatic=True)
    if family == "payload":
        return draw_robot(rng, str(rng.choice(["dh", "mdh"])), masses=True)
    if family == "urdf":
        return draw_robot(rng, "urdf")
    if family == "urdf-mimic":
        return draw_robot(rng, "urdf", dof=int(rng.integers(5, 8)), n_mimic=int(rng.integers(1, 3)))
    if family == "urdf-prismatic":
        return draw_robot(rng, "urdf", column=True)
    if family == "urdf-two-tips":
        return draw_robot(rng, "urdf", two_tips=True)
    if family == "constant-orientation":
        return draw_robot(rng, "dh", dof=6, template=True)
    if family in ("wrong-swap", "wrong-length", "slip-file-mm", "slip-file-deg"):
        return draw_robot(rng, "dh", units={"slip-file-mm": ("mm", "deg"), "slip-file-deg": ("m", "deg")}.get(family))
    return draw_robot(rng, str(rng.choice(["dh", "mdh", "urdf"])) if family in ("tracker", "noise", "sweeps") else "dh")


def draw_campaign(family: str, seed: int) -> Campaign:
    """Draw campaign ``seed`` of ``family`` (a key of :data:`FAMILIES`)."""
    if family not in FAMILIES:
        raise ValueError(f"unknown battery family {family!r}; choose one of {', '.join(FAMILIES)}")
    rng = np.random.default_rng([int(seed), list(FAMILIES).index(family)])
    rr = _family_robot(family, rng)
    n_test = 40
    n_train = int(rng.integers(80, 160))
    has_rot = True
    if family == "few-poses":
        n_train = int(math.ceil(minimum_fit_rows(rr.nominal, True) * rng.uniform(1.0, 1.5)))
    meas: dict = {"noise_m": float(rng.uniform(0.01, 0.03)) * 1e-3, "noise_rad": float(rng.uniform(0.001, 0.003)) * _DEG}
    if family in ("tracker", "position-only", "reflectors3", "stations", "constant-orientation"):
        meas["frame"] = _tracker_frame(rng, 1.0, 6.0)  # every TCP < 10 m from the tracker
    elif family == "tracker-far":
        meas["frame"] = _tracker_frame(rng, 10.0, 2000.0)
    if family == "position-only":
        meas["orientation"], has_rot = False, False
    if family == "reflectors3":
        meas["orientation"], has_rot = False, False
        meas["reflectors"] = np.array([[rng.uniform(0.06, 0.12), 0.0, 0.0], [0.0, rng.uniform(0.06, 0.12), 0.0]])
    if family == "noise":
        meas["noise_m"] = float(np.exp(rng.uniform(np.log(0.005), np.log(0.2)))) * 1e-3
        meas["noise_rad"] = float(np.exp(rng.uniform(np.log(0.001), np.log(0.02)))) * _DEG
    n = n_train + n_test
    if family == "constant-orientation":
        q = _constant_orientation_joints(rr, n, rng)
    elif family == "sweeps":
        q = _sweep_joints(rr, n, rng)
    elif family == "subregion":
        span = rr.upper - rr.lower
        lo = rr.lower + rng.uniform(0.05, 0.65, rr.dof) * span
        q = lo + rng.random((n, rr.dof)) * 0.3 * span
    else:
        q = rr.random_joints(n, rng)
    q = q[rng.permutation(n)] if family != "thermal" else q
    if family == "payload":
        kinds = rng.choice([0.0, 5.0, 10.0, 20.0], size=int(rng.integers(2, 4)), replace=False)
        meas["payload_kg"] = np.resize(kinds, n)
    if family == "thermal":
        th = ThermalDrift(coefficient_per_k=float(rng.choice([11.5e-6, 23e-6])), reference_c=20.0, start_c=20.0,
                          end_c=20.0 + float(rng.uniform(4, 10)), time_constant_samples=n / 3)
        meas["thermal"], meas["temperature"] = th, th.temperature_c(np.arange(n))
    if family == "stations":
        k = int(rng.integers(2, 4))
        label = np.arange(n) % k
        parts_q, parts_d = [], []
        meas.pop("frame")
        ds_all, p_all = None, np.zeros((n, 3))
        for s in range(k):  # stations around the robot, 2.9-3.5 m from it: 5-7 m apart
            fr = se3.rotz(2 * math.pi * s / k) @ se3.trans(rng.uniform(2.9, 3.5), 0.0, rng.uniform(-0.5, 0.5))
            ds_s, p_s = _measure(rr, q[label == s], rng, frame=fr @ se3.make_transform(_random_rotation(rng), np.zeros(3)), **meas)
            parts_d.append(ds_s)
            p_all[label == s] = p_s
            parts_q.append(np.flatnonzero(label == s))
        order = np.concatenate(parts_q)
        inv = np.argsort(order)
        from ..io.dataset import concat

        ds_all = concat(parts_d)
        ds_all = Dataset(q=ds_all.q[inv], xyz_m=ds_all.xyz_m[inv], quat_wxyz=ds_all.quat_wxyz[inv],
                         extra={"station": np.array(["ABC"[s] for s in label])}, source="battery")
        ds, p_true = ds_all, p_all
    else:
        ds, p_true = _measure(rr, q, rng, **meas)
    train, test = _split(ds, n_train)
    c = Campaign(family=family, seed=int(seed), robot=rr, train=train, test=test, expect="model",
                 floor_mm=_floor_mm(test, p_true[n_train:]), describe=f"{FAMILIES[family]}; {rr.describe}; "
                 f"{n_train} training poses, noise {meas['noise_m'] * 1e3:.3f} mm")
    if rr.tip is not None:
        c.fit_args += ["--tip", rr.tip]
    _mistake(c, rng, has_rot)
    return c


def _mistake(c: Campaign, rng, has_rot: bool) -> None:
    """Apply the family's user mistake to ``c`` (files, options, expected outcome)."""
    f, rr = c.family, c.robot
    if f == "data-units":
        c.write_units = ("mm", "deg")
        c.fit_args += ["--length-unit", "mm", "--angle-unit", "deg"]
        c.eval_args += ["--length-unit", "mm", "--angle-unit", "deg"]
    elif f == "few-poses":
        c.expect, c.causes = "model-or-refuse", ("too few", "poses")
    elif f == "wrong-swap":
        i = int(rng.integers(0, rr.nominal.dof - 2))
        order = np.arange(rr.nominal.dof)
        order[[i, i + 1]] = order[[i + 1, i]]
        nom = rr.nominal  # the geometry rows swapped, the limits kept (they would give it away at once)
        wrong = nom.copy(**{k: getattr(nom, k)[order] for k in ("a_m", "alpha_rad", "d_m", "theta_rad")})
        c.robot_text = robot_to_toml_string(wrong, *rr.units)
        c.expect, c.causes = "model-or-refuse", ("robot file", "check the robot", "implausib", "does not fit", "converge")
        c.describe += f"; joints {i + 1} and {i + 2} swapped in the file"
    elif f == "wrong-length":
        nom = rr.nominal
        key = str(rng.choice(["a_m", "d_m"]))
        vals = getattr(nom, key).copy()
        j = int(rng.choice(np.flatnonzero(vals != 0))) if np.any(vals != 0) else 0
        dv = float(rng.uniform(0.02, 0.10) * rng.choice([-1, 1]))
        vals[j] += dv
        c.robot_text = robot_to_toml_string(nom.copy(**{key: vals}), *rr.units)
        c.expect, c.causes = "model-or-refuse", ("robot file", "check the robot", "implausib", "does not fit", key[0])
        c.describe += f"; {key[0]} of joint {j + 1} off by {dv * 1e3:.0f} mm in the file"
    elif f == "slip-mm":
        for ds in (c.train, c.test):
            ds.xyz_m = ds.xyz_m * 1e3
        c.expect, c.causes = "refuse", _UNIT_CAUSES
    elif f == "slip-deg":
        for ds in (c.train, c.test):
            ds.q = np.degrees(ds.q)
        c.expect, c.causes = "refuse", ("degree", "deg", "angle-unit", "angle unit")
    elif f == "slip-xyzw":
        for ds in (c.train, c.test):
            ds.quat_wxyz = np.roll(ds.quat_wxyz, -1, axis=1)
        # on an arm that turns its tool about one axis only (all axes parallel) the misread rotations
        # are those of another tool orientation: nothing can tell, and a model at the floor is right
        c.expect, c.causes = "model-or-refuse", ("scalar", "xyzw", "quaternion", "order")
    elif f == "slip-file-mm":
        c.robot_text = rr.file_text.replace('length_unit = "mm"', 'length_unit = "m"')
        c.expect, c.causes = "refuse", ("length_unit", "robot file")
    elif f == "slip-file-deg":
        c.robot_text = rr.file_text.replace('angle_unit = "deg"', 'angle_unit = "rad"')
        c.expect, c.causes = "refuse", ("angle_unit", "robot file")
