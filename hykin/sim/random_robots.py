"""Random serial robots, as robot makers and users write them, with a "true" robot behind each.

A :class:`RandomRobot` holds the text of a robot file (TOML in any of the units DESIGN.md §3 allows,
or a URDF with fixed joints, ``<mimic>`` joints, prismatic joints and dead-end branches), the robot
that file describes (``nominal``) and the robot that really moves (``truth``: the file's robot with
geometry off by 0.1–2 mm / 0.01–0.2°, joint zeros off, base and tool off, optionally compliance).

Both robots are built here directly from the drawn numbers (not by reading the file back), so they
are an independent reference for hykin's file readers. A URDF's ``<mimic>`` joints are kept as
joints of ``nominal`` / ``truth``; :meth:`RandomRobot.full_joints` maps the independent joints (the
dataset's ``q1..qN``, DESIGN.md §3) to all of them (``q_mimic = multiplier * q_leader + offset``).

Used by :mod:`hykin.sim.random_campaigns` (measurement campaigns), the generated test battery
(``tests/test_battery.py``) and ``benchmarks/bench_battery.py``. Depends on :mod:`hykin.io`,
:mod:`hykin.kinematics`, :mod:`hykin.geometry`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3
from ..io.robot_toml import robot_to_toml_string
from ..kinematics.robot import Robot, dh_to_mdh
from .simulate import geometric_deviation, mass_deviation

__all__ = ["RandomRobot", "draw_robot", "perturb", "random_dh", "random_urdf"]

_DEG = math.pi / 180


@dataclass
class RandomRobot:
    """A drawn robot: its file, the robot the file describes and the true one.

    kind: ``"dh"``, ``"mdh"`` or ``"urdf"``. file_text / suffix: the robot file (``.toml``/``.urdf``).
    nominal, truth: :class:`Robot` with every movable joint of the chain (mimic joints included).
    mimic_matrix ``(n_all, n_ind)`` / mimic_offset ``(n_all,)``: ``q_all = q_ind @ M.T + c`` (identity
    without mimic joints). tip: the tip link a user must name (``--tip``), or None.
    lower, upper: ``(n_ind,)`` limits of the independent joints (rad, m for prismatic).
    describe: one line saying what was drawn (for failure reports).
    sigma_m, sigma_rad: the σ of the truth's geometric errors (m, rad; :func:`perturb`).
    """

    kind: str
    file_text: str
    suffix: str
    nominal: Robot
    truth: Robot
    mimic_matrix: np.ndarray
    mimic_offset: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    tip: str | None = None
    describe: str = ""
    units: tuple[str, str] = ("m", "rad")
    extra: dict = field(default_factory=dict)
    sigma_m: float = 0.0
    sigma_rad: float = 0.0

    @property
    def dof(self) -> int:
        """Number of independent joints (the dataset's joint columns)."""
        return int(self.mimic_matrix.shape[1])

    def full_joints(self, q_ind) -> np.ndarray:
        """``(N, n_all)`` joints of every movable joint from the independent ones ``(N, n_ind)``."""
        q = np.atleast_2d(np.asarray(q_ind, dtype=np.float64))
        return q @ self.mimic_matrix.T + self.mimic_offset

    def random_joints(self, n: int, rng, margin: float = 0.05) -> np.ndarray:
        """``(n, n_ind)`` independent joints uniform within limits shrunk by ``margin`` of each range."""
        span = self.upper - self.lower
        lo, hi = self.lower + margin * span, self.upper - margin * span
        return lo + rng.random((n, self.dof)) * (hi - lo)


# --------------------------------------------------------------------------- DH / MDH


def _template_6r(rng) -> tuple[np.ndarray, ...]:
    """(a, alpha, d, theta) of a 6R arm as makers build them: an industrial arm with a spherical wrist
    (RX160 / KUKA-like) or a UR-like arm with three parallel axes, link lengths drawn."""
    h = math.pi / 2
    if rng.random() < 0.5:
        a = np.array([rng.uniform(0.05, 0.4), rng.uniform(0.4, 1.2), rng.uniform(0.0, 0.2), 0, 0, 0])
        d = np.array([rng.uniform(0.3, 0.8), 0, 0, rng.uniform(0.4, 1.2), 0, rng.uniform(0.05, 0.2)])
        return a, np.array([-h, 0, h, -h, h, 0]), d, np.array([0, -h, h, 0, 0, 0])
    a = np.array([0, -rng.uniform(0.3, 0.7), -rng.uniform(0.3, 0.6), 0, 0, 0])
    d = np.array([rng.uniform(0.08, 0.2), 0, 0, rng.uniform(0.1, 0.2), rng.uniform(0.09, 0.12), rng.uniform(0.08, 0.12)])
    return a, np.array([h, 0, 0, h, -h, 0]), d, np.zeros(6)


def random_dh(rng: np.random.Generator, dof: int, prismatic_first: bool = False, masses: bool = False,
              template: bool | None = None) -> Robot:
    """A standard-DH arm with ``dof`` joints: twists 0 / ±90°, link lengths 0.05–1.2 m (total reach
    ≤ 3 m), never two coinciding consecutive axes, joint limits ±100–270°, a 0.05–0.3 m tool;
    optionally a prismatic first joint (a linear column, 0.3–1.5 m stroke) and masses/stiffness.
    With ``template`` (default: half of the 6-joint arms) the geometry is a maker's layout
    (:func:`_template_6r`) with drawn lengths."""
    template = (dof == 6 and rng.random() < 0.5) if template is None else template
    a, d = np.zeros(dof), np.zeros(dof)
    alpha = rng.choice([0.0, math.pi / 2, -math.pi / 2], size=dof, p=[0.3, 0.35, 0.35])
    theta = rng.choice([0.0, math.pi / 2, -math.pi / 2], size=dof, p=[0.6, 0.2, 0.2])
    for i in range(dof if not template else 0):
        if rng.random() < 0.5:
            a[i] = rng.uniform(0.05, 1.2)
        if rng.random() < 0.5:
            d[i] = rng.uniform(0.05, 1.2)
        if abs(alpha[i]) < 1e-9 and a[i] == 0.0:  # parallel axes must not coincide
            a[i] = rng.uniform(0.05, 1.2)
    alpha[-1], a[-1], d[-1] = 0.0, 0.0, rng.uniform(0.05, 0.25)  # flange on the last axis
    if template:
        a, alpha, d, theta = _template_6r(rng)
    reach = float(np.hypot(a, d).sum())
    if reach > 3.0:
        a, d = a * 3.0 / reach, d * 3.0 / reach
    lower = -rng.uniform(100, 270, dof) * _DEG
    upper = rng.uniform(100, 270, dof) * _DEG
    types = ["revolute"] * dof
    if prismatic_first:
        types[0], theta[0] = "prismatic", 0.0
        lower[0], upper[0] = 0.0, rng.uniform(0.3, 1.5)
    tool = se3.xyzrpy_to_transform([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.05, 0.3)],
                                   rng.choice([0.0, 0.0, math.pi / 2], 3))
    kw = {}
    if masses:
        kw["mass_kg"] = rng.uniform(2, 40, dof) * np.linspace(1.0, 0.1, dof)
        kw["com_m"] = rng.uniform(-0.1, 0.1, (dof, 3))
        kw["stiffness_nm_per_rad"] = rng.uniform(3e5, 2e6, dof)
    return Robot(name="random-arm", convention="dh", a_m=a, alpha_rad=alpha, d_m=d, theta_rad=theta,
                 lower=lower, upper=upper, joint_type=tuple(types), tool=tool, **kw)


# --------------------------------------------------------------------------- URDF


def _axis_choice(rng) -> np.ndarray:
    ax = np.zeros(3)
    ax[rng.integers(3)] = rng.choice([-1.0, 1.0])
    return ax


def _urdf_joint_xml(j: dict) -> str:
    xyz, rpy = se3.transform_to_xyzrpy(j["origin"])
    f = lambda v: " ".join(repr(float(x)) for x in v)
    s = (f'  <joint name="{j["name"]}" type="{j["type"]}"><parent link="{j["parent"]}"/><child link="{j["child"]}"/>'
         f'<origin xyz="{f(xyz)}" rpy="{f(rpy)}"/>')
    if j["type"] != "fixed":
        s += f'<axis xyz="{f(j["axis"])}"/><limit lower="{j["lower"]!r}" upper="{j["upper"]!r}" effort="100" velocity="1"/>'
    if j.get("mimic"):
        leader, mult, off = j["mimic"]
        s += f'<mimic joint="{leader}" multiplier="{mult!r}" offset="{off!r}"/>'
    return s + "</joint>"


def random_urdf(rng: np.random.Generator, dof: int, n_mimic: int = 0, branches: bool = True,
                two_tips: bool = False, column: bool = False) -> tuple[str, list[dict], str | None]:
    """A maker-style URDF of an arm with ``dof`` independent joints: joint origins with rpy of 0 / ±90°,
    axes along ±x/±y/±z, fixed joints inside the chain and at the flange / TCP, dead-end branches
    (a camera on a fixed joint, a cable guide), and with ``n_mimic`` > 0 a lifting column whose
    actuated prismatic joint drives ``n_mimic`` telescopic stages through ``<mimic>`` (``column``: the
    lifting column without stages). With
    ``two_tips`` a second TCP hangs off the flange as far from the base as ``tool0`` (the user must
    name the tip). Returns ``(urdf_text, chain_joints, tip_to_name)``; ``chain_joints`` lists the main
    chain base -> tip (dicts: name, type, origin 4x4, axis, lower, upper, mimic)."""
    chain: list[dict] = []
    side: list[dict] = []
    links = ["base_link"]

    def add(kind, origin, axis=None, lower=0.0, upper=0.0, mimic=None, name=None, into=chain, parent=None):
        k = len(links)
        child = f"{name or 'link'}_{k}"
        j = {"name": f"joint_{k}" if name is None else f"{name}_joint_{k}", "type": kind,
             "parent": parent or (chain[-1]["child"] if chain else "base_link"), "child": child, "origin": origin,
             "axis": axis, "lower": float(lower), "upper": float(upper), "mimic": mimic}
        links.append(child)
        into.append(j)
        return j

    rpy_choices = [0.0, 0.0, math.pi / 2, -math.pi / 2]
    if rng.random() < 0.5:  # a mounting plate
        add("fixed", se3.xyzrpy_to_transform([0, 0, rng.uniform(0.0, 0.2)], [0, 0, rng.choice(rpy_choices)]), name="mount")
    n_rev = dof
    if n_mimic > 0 or column:
        lead = add("prismatic", se3.xyzrpy_to_transform([0, 0, rng.uniform(0.3, 0.8)], [0, 0, 0]), [0, 0, 1.0],
                   0.0, rng.uniform(0.3, 0.8), name="column")
        for _ in range(n_mimic):
            mult, off = float(rng.uniform(0.5, 1.0)), float(rng.uniform(-0.02, 0.02))
            add("prismatic", se3.xyzrpy_to_transform([0, 0, rng.uniform(0.05, 0.3)], [0, 0, 0]), [0, 0, 1.0],
                min(0.0, off) - 0.05, mult * lead["upper"] + abs(off) + 0.05, mimic=(lead["name"], mult, off), name="stage")
        n_rev = dof - 1
    prev_axis_world, T_world = None, np.eye(4)
    for i in range(n_rev):
        for _ in range(50):
            xyz = np.zeros(3)
            comps = rng.choice(3, size=rng.integers(1, 3), replace=False)
            xyz[comps] = rng.uniform(0.05, 1.2, len(comps)) * rng.choice([-1.0, 1.0], len(comps)) / len(comps)
            if i == 0:
                xyz = np.array([0.0, 0.0, rng.uniform(0.1, 0.6)])
            origin = se3.xyzrpy_to_transform(xyz, rng.choice(rpy_choices, 3))
            axis = _axis_choice(rng)
            Tj = T_world @ origin
            aw, pw = Tj[:3, :3] @ axis, Tj[:3, 3]
            if prev_axis_world is None:
                break
            (pa, pp) = prev_axis_world
            if abs(abs(aw @ pa) - 1.0) > 1e-6:
                break
            off = (pw - pp) - ((pw - pp) @ pa) * pa  # parallel axes: distance between them
            if np.linalg.norm(off) > 0.05:
                break
        lim = rng.uniform(100, 270) * _DEG
        add("revolute", origin, axis, -lim, rng.uniform(100, 270) * _DEG)
        T_world, prev_axis_world = Tj, (aw, pw)
        if branches and i == 1 and rng.random() < 0.7:  # dead-end branch: a cable guide on link 2
            add("fixed", se3.xyzrpy_to_transform([0.1, 0.05, 0], [0, 0, 0]), name="cable_guide", into=side,
                parent=chain[-1]["child"])
        if i < n_rev - 1 and rng.random() < 0.3:  # a fixed joint inside the chain
            fx = add("fixed", se3.xyzrpy_to_transform(rng.uniform(-0.1, 0.1, 3), rng.choice(rpy_choices, 3)), name="fixed")
            T_world = T_world @ fx["origin"]
    add("fixed", se3.xyzrpy_to_transform([0, 0, rng.uniform(0.0, 0.1)], [0, 0, 0]), name="flange")
    flange = chain[-1]["child"]
    tool = se3.xyzrpy_to_transform([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.05, 0.3)],
                                   [0, 0, rng.choice(rpy_choices)])
    tcp = add("fixed", tool, name="tool0")
    tip = None
    if branches:
        add("fixed", se3.xyzrpy_to_transform([0.05, 0, 0.05], [0, math.pi / 2, 0]), name="camera", into=side,
            parent=chain[1]["child"] if len(chain) > 1 else "base_link")
    if two_tips:
        add("fixed", se3.xyzrpy_to_transform([0.0, 0.08, 0.12], [0, 0, 0]), name="tool1", into=side, parent=flange)
        tip = tcp["child"]
    body = ['<?xml version="1.0"?>\n<robot name="random-urdf-arm">']
    body += [f'  <link name="{ln}"/>' for ln in links]
    body += [_urdf_joint_xml(j) for j in chain + side]
    body.append("</robot>\n")
    return "\n".join(body), chain, tip


def _urdf_robot(chain: list[dict]) -> Robot:
    """The :class:`Robot` (convention "urdf") of a main chain: fixed joints folded into the next
    movable joint's origin, those after the last movable joint into the tool."""
    pending, origins, axes, types, lo, hi = np.eye(4), [], [], [], [], []
    for j in chain:
        if j["type"] == "fixed":
            pending = pending @ j["origin"]
            continue
        origins.append(pending @ j["origin"])
        pending = np.eye(4)
        axes.append(j["axis"])
        types.append(j["type"])
        lo.append(j["lower"])
        hi.append(j["upper"])
    xyz, rpy = se3.transform_to_xyzrpy(np.array(origins))
    n = len(origins)
    z = np.zeros(n)
    return Robot(name="random-urdf-arm", convention="urdf", a_m=z, alpha_rad=z, d_m=z, theta_rad=z, lower=lo, upper=hi,
                 origin_xyz_m=xyz, origin_rpy_rad=rpy, axis=np.array(axes), joint_type=tuple(types), tool=pending)


def _mimic_map(chain: list[dict]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """``(M, c, rows)``: ``q_all = q_ind @ M.T + c`` and the rows of the independent joints in ``q_all``."""
    movable = [j for j in chain if j["type"] != "fixed"]
    ind = [j["name"] for j in movable if not j.get("mimic")]
    M, c = np.zeros((len(movable), len(ind))), np.zeros(len(movable))
    for r, j in enumerate(movable):
        if j.get("mimic"):
            leader, mult, off = j["mimic"]
            M[r, ind.index(leader)], c[r] = mult, off
        else:
            M[r, ind.index(j["name"])] = 1.0
    return M, c, [r for r, j in enumerate(movable) if not j.get("mimic")]


# --------------------------------------------------------------------------- truth


def perturb(robot: Robot, rng: np.random.Generator, sigma_m: float, sigma_rad: float, compliance: bool = False) -> Robot:
    """The "true" robot: ``robot`` with Gaussian geometry and joint-zero errors (σ ``sigma_m``,
    ``sigma_rad``), base and tool off by the same σ, and with ``compliance`` stiffness off by
    ±30 % and masses by 5 %. DH/MDH: :func:`hykin.sim.simulate.geometric_deviation`; URDF: every
    joint origin moved and turned, revolute zeros turned about the joint axis."""
    if robot.convention in ("dh", "mdh"):
        t = geometric_deviation(robot, rng, sigma_m, sigma_rad, sigma_m, sigma_rad)
    else:
        n = robot.dof
        T = se3.xyzrpy_to_transform(robot.origin_xyz_m, robot.origin_rpy_rad)
        dT = se3.make_transform(se3.rotvec_to_matrix(rng.normal(0, sigma_rad, (n, 3))), rng.normal(0, sigma_m, (n, 3)))
        zero = rng.normal(0, sigma_rad, n) * np.array([jt == "revolute" for jt in robot.joint_type])
        T = T @ dT @ se3.make_transform(se3.rotvec_to_matrix(robot.axis * zero[:, None]), np.zeros((n, 3)))
        xyz, rpy = se3.transform_to_xyzrpy(T)
        frame = lambda: se3.make_transform(se3.rotvec_to_matrix(rng.normal(0, sigma_rad, 3)), rng.normal(0, sigma_m, 3))
        t = robot.copy(origin_xyz_m=xyz, origin_rpy_rad=rpy, base=robot.base @ frame(), tool=robot.tool @ frame())
    if compliance and robot.has_compliance:
        t = mass_deviation(t, rng).copy(stiffness_nm_per_rad=robot.stiffness_nm_per_rad * rng.uniform(0.7, 1.3, robot.dof))
    return t


def draw_robot(rng: np.random.Generator, kind: str = "dh", dof: int | None = None, *, units=None,
               prismatic: bool = False, masses: bool = False, n_mimic: int = 0, branches: bool = True,
               two_tips: bool = False, sigma_m: float | None = None, sigma_rad: float | None = None,
               template: bool | None = None, column: bool = False) -> RandomRobot:
    """Draw a robot of ``kind`` ("dh", "mdh", "urdf") with ``dof`` independent joints (default 4–7),
    its file (TOML in ``units`` = (length, angle) unit, default drawn from m/mm × deg/rad; URDF in
    m/rad as URDF requires) and its truth (geometry σ default drawn in 0.1–2 mm, 0.01–0.2°)."""
    dof = int(rng.integers(4, 8)) if dof is None else int(dof)
    sigma_m = float(rng.uniform(0.1e-3, 2e-3)) if sigma_m is None else sigma_m
    sigma_rad = float(rng.uniform(0.01, 0.2) * _DEG) if sigma_rad is None else sigma_rad
    tip = None
    if kind in ("dh", "mdh"):
        nominal = random_dh(rng, dof, prismatic_first=prismatic, masses=masses, template=template)
        if kind == "mdh":
            nominal = dh_to_mdh(nominal)
        if units is None:
            units = (str(rng.choice(["m", "mm"])), str(rng.choice(["deg", "rad"])))
        text, suffix = robot_to_toml_string(nominal, *units), ".toml"
        M, c = np.eye(dof), np.zeros(dof)
        lower, upper = nominal.lower, nominal.upper
        desc = f"{kind} {dof} joints" + (" prismatic-first" if prismatic else "") + (" masses" if masses else "")
    elif kind == "urdf":
        text, chain, tip = random_urdf(rng, dof, n_mimic=n_mimic, branches=branches, two_tips=two_tips, column=column)
        nominal = _urdf_robot(chain)
        M, c, rows = _mimic_map(chain)
        lower, upper = nominal.lower[rows], nominal.upper[rows]
        suffix, units = ".urdf", ("m", "rad")
        desc = f"urdf {dof} independent joints, {n_mimic} mimic" + (", prismatic column" if column or n_mimic else "") + (", branches" if branches else "") + (
            ", two tips" if two_tips else "")
    else:
        raise ValueError(f"robot kind must be dh, mdh or urdf, got {kind!r}")
    truth = perturb(nominal, rng, sigma_m, sigma_rad, compliance=masses)
    desc += f", file in {units[0]}/{units[1]}, truth off by {sigma_m * 1e3:.2f} mm / {sigma_rad / _DEG:.3f} deg"
    return RandomRobot(kind=kind, file_text=text, suffix=suffix, nominal=nominal, truth=truth, mimic_matrix=M,
                       mimic_offset=c, lower=np.asarray(lower, float), upper=np.asarray(upper, float), tip=tip,
                       describe=desc, units=tuple(units), sigma_m=sigma_m, sigma_rad=sigma_rad)
