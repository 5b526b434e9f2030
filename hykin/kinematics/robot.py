"""Robot definitions: the :class:`Robot` dataclass and exact DH <-> MDH conversions.

A robot is plain data: per-joint geometry arrays in SI units, limits, optional mass properties and
joint stiffness, plus base and tool transforms. Kinematics live in :mod:`hykin.kinematics.chain`,
:mod:`hykin.kinematics.fk` and :mod:`hykin.kinematics.ik`; robot files (TOML, URDF, presets) are
read and written by :mod:`hykin.io.robot_toml`, :mod:`hykin.io.urdf` and :mod:`hykin.io.robot_file`.

Geometry conventions (``Robot.convention``):

* ``"dh"`` (standard, Denavit-Hartenberg): joint i contributes
  ``Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``; link frame i is the frame after it.
* ``"mdh"`` (modified, Craig): joint i contributes
  ``Rx(alpha_i) Tx(a_i) Ry(beta_i) Rz(theta_i + q_i) Tz(d_i)``; link frame i is the frame after it.
* ``"urdf"``: joint i contributes ``origin_i Rot(axis_i, q_i)`` (or ``Trans(axis_i q_i)`` for a
  prismatic joint); link frame i is the URDF child link frame.

``beta`` (Hayati's rotation about y) is zero in nominal models; calibration uses it for near-parallel
consecutive axes where DH is ill-conditioned. For prismatic joints in DH/MDH, ``q`` adds to ``d``.

Mimic joints (URDF ``<mimic>``): the chain may hold more joints than the robot has independent
(actuated) joints. ``mimic`` ``(n_chain, 3)`` gives per chain joint ``[leader, multiplier, offset]``:
``leader = -1`` for an independent joint, else the chain index of the independent joint it follows,
``q_chain = multiplier · q_leader + offset``. :attr:`Robot.dof` counts independent joints (what data
and the API give), :attr:`Robot.n_chain` chain joints. Per-chain-joint fields: geometry arrays,
``joint_type``, ``mass_kg``, ``com_m``, ``stiffness_nm_per_rad``, ``joint_names``; per independent
joint: ``lower``, ``upper`` (and :attr:`Robot.independent_joint_type`). The expansion from independent
to chain joints happens in one place, :func:`hykin.kinematics.walk.expand_joints`.

World/measurement frame -> robot base is ``base``; flange (last link frame) -> TCP is ``tool``.
Gravity acts along ``gravity_base`` (m/s^2, in the robot base frame; default ``(0, 0, -9.81)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry import se3

__all__ = ["CONVENTIONS", "Robot", "RobotFileError", "dh_to_mdh", "mdh_to_dh", "robot_reach_m"]

CONVENTIONS = ("dh", "mdh", "urdf")


class RobotFileError(ValueError):
    """A robot file (TOML or URDF) or a robot's fields are malformed; the message names the file
    (or robot) and the field. Defined here, beside :class:`Robot` which raises it, so that every
    robot-file reader in :mod:`hykin.io` can import it without an import cycle."""


@dataclass
class Robot:
    """A serial robot: geometry, limits, mass properties, base and tool. All SI (m, rad, kg).

    Attributes
    ----------
    name: robot name.
    convention: ``"dh"``, ``"mdh"`` or ``"urdf"`` (see module docstring).
    a_m, alpha_rad, d_m, theta_rad, beta_rad: ``(n,)`` DH/MDH parameters (zeros for URDF robots).
    origin_xyz_m, origin_rpy_rad, axis: ``(n, 3)`` URDF joint origins and unit axes (URDF only).
    joint_type: ``(n,)`` strings ``"revolute"`` or ``"prismatic"``.
    lower, upper: ``(dof,)`` limits of the independent joints (rad, or m for prismatic joints).
    mass_kg: ``(n,)`` link masses (zeros if unknown).
    com_m: ``(n, 3)`` centre of mass of link i in link frame i.
    stiffness_nm_per_rad: ``(n,)`` joint stiffness; ``inf`` = rigid.
    base: ``(4, 4)`` world/measurement frame -> robot base.
    tool: ``(4, 4)`` flange -> TCP.
    payload_kg: point mass at the TCP.
    gravity_base: ``(3,)`` gravity vector in the robot base frame, m/s^2.
    source: where the numbers come from (free text, kept in saved files).
    mimic: ``(n_chain, 3)`` ``[leader chain index or -1, multiplier, offset]`` or None (no mimic joints).
    joint_names: ``(n_chain,)`` joint names (URDF joint names) or None (``q1..qN``).
    urdf: for robots read from a URDF, ``{"xml": text, "base_link": ..., "tip_link": ..., "continuous":
        space-separated names of continuous joints}`` (so that a calibrated robot can be written back as
        the maker's URDF), else None.
    """

    name: str
    convention: str
    a_m: np.ndarray
    alpha_rad: np.ndarray
    d_m: np.ndarray
    theta_rad: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    beta_rad: np.ndarray | None = None
    origin_xyz_m: np.ndarray | None = None
    origin_rpy_rad: np.ndarray | None = None
    axis: np.ndarray | None = None
    joint_type: tuple[str, ...] | None = None
    mass_kg: np.ndarray | None = None
    com_m: np.ndarray | None = None
    stiffness_nm_per_rad: np.ndarray | None = None
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool: np.ndarray = field(default_factory=lambda: np.eye(4))
    payload_kg: float = 0.0
    gravity_base: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    source: str = ""
    mimic: np.ndarray | None = None
    joint_names: tuple[str, ...] | None = None
    urdf: dict | None = None

    def __post_init__(self) -> None:
        if self.convention not in CONVENTIONS:
            raise RobotFileError(f"robot {self.name!r}: convention must be one of {CONVENTIONS}, got {self.convention!r}")
        f = lambda x: np.array(x, dtype=np.float64, copy=True)
        self.a_m, self.alpha_rad, self.d_m, self.theta_rad = map(f, (self.a_m, self.alpha_rad, self.d_m, self.theta_rad))
        n = self.a_m.shape[0]
        for nm in ("alpha_rad", "d_m", "theta_rad"):
            if getattr(self, nm).shape != (n,):
                raise RobotFileError(f"robot {self.name!r}: {nm} has shape {getattr(self, nm).shape}, expected ({n},)")
        self.lower, self.upper = f(self.lower), f(self.upper)
        self._check_mimic(n)
        if self.joint_names is not None:
            self.joint_names = tuple(str(x) for x in self.joint_names)
            if len(self.joint_names) != n:
                raise RobotFileError(f"robot {self.name!r}: {len(self.joint_names)} joint_names for {n} joints")
        if self.lower.shape != (self.dof,) or self.upper.shape != (self.dof,):
            raise RobotFileError(f"robot {self.name!r}: lower/upper must have shape ({self.dof},) (one per independent joint)")
        self.beta_rad = np.zeros(n) if self.beta_rad is None else f(self.beta_rad)
        self.origin_xyz_m = np.zeros((n, 3)) if self.origin_xyz_m is None else f(self.origin_xyz_m).reshape(n, 3)
        self.origin_rpy_rad = np.zeros((n, 3)) if self.origin_rpy_rad is None else f(self.origin_rpy_rad).reshape(n, 3)
        if self.axis is None:
            self.axis = np.tile([0.0, 0.0, 1.0], (n, 1))
        else:
            ax = f(self.axis).reshape(n, 3)
            self.axis = ax / np.linalg.norm(ax, axis=1, keepdims=True)
        self.joint_type = tuple(self.joint_type) if self.joint_type is not None else ("revolute",) * n
        if len(self.joint_type) != n or any(t not in ("revolute", "prismatic") for t in self.joint_type):
            raise RobotFileError(f"robot {self.name!r}: joint_type must be {n} of 'revolute'/'prismatic'")
        self.mass_kg = np.zeros(n) if self.mass_kg is None else f(self.mass_kg)
        self.com_m = np.zeros((n, 3)) if self.com_m is None else f(self.com_m).reshape(n, 3)
        self.stiffness_nm_per_rad = (
            np.full(n, np.inf) if self.stiffness_nm_per_rad is None else f(self.stiffness_nm_per_rad)
        )
        self.base, self.tool = f(self.base).reshape(4, 4), f(self.tool).reshape(4, 4)
        self.gravity_base = f(self.gravity_base).reshape(3)
        self.payload_kg = float(self.payload_kg)
        if np.any(self.lower > self.upper):
            j = int(np.argmax(self.lower > self.upper))
            raise RobotFileError(f"robot {self.name!r}: joint {j + 1} has min > max")

    def _check_mimic(self, n: int) -> None:
        if self.mimic is None:
            return
        m = np.array(self.mimic, dtype=np.float64, copy=True).reshape(n, 3)
        lead = m[:, 0]
        for i in range(n):
            k = lead[i]
            if k < 0:
                continue
            if k != int(k) or not 0 <= k < n or lead[int(k)] >= 0 or int(k) == i:
                raise RobotFileError(f"robot {self.name!r}: mimic joint {i + 1} follows {k:g}, which is not an independent joint")
            if not (np.isfinite(m[i, 1]) and np.isfinite(m[i, 2])):
                raise RobotFileError(f"robot {self.name!r}: mimic joint {i + 1}: multiplier/offset must be finite")
        self.mimic = None if np.all(lead < 0) else m

    @property
    def dof(self) -> int:
        """Number of independent joints (the columns of joint data); ``n_chain`` minus mimic joints."""
        n = int(self.a_m.shape[0])
        return n if self.mimic is None else int(np.sum(self.mimic[:, 0] < 0))

    @property
    def n_chain(self) -> int:
        """Number of movable joints in the kinematic chain (mimic joints included)."""
        return int(self.a_m.shape[0])

    @property
    def independent(self) -> np.ndarray:
        """``(dof,)`` chain indices of the independent joints, in chain order."""
        if self.mimic is None:
            return np.arange(self.n_chain)
        return np.flatnonzero(self.mimic[:, 0] < 0)

    @property
    def independent_joint_type(self) -> tuple[str, ...]:
        """``joint_type`` of the independent joints (``(dof,)``: the types of the joint data columns)."""
        if self.mimic is None:
            return self.joint_type
        return tuple(self.joint_type[i] for i in self.independent)

    @property
    def revolute(self) -> np.ndarray:
        """``(dof,)`` bool: independent joints that are revolute (rad; the others prismatic, m)."""
        return np.array([t == "revolute" for t in self.independent_joint_type], dtype=bool)

    @property
    def independent_joint_names(self) -> tuple[str, ...] | None:
        """Names of the independent joints (URDF joint names) or None."""
        if self.joint_names is None:
            return None
        return tuple(self.joint_names[i] for i in self.independent)

    @property
    def continuous(self) -> np.ndarray:
        """``(dof,)`` bool: independent joints that are URDF ``continuous`` (revolute without limits).

        hykin gives them the range ``[-pi, pi]`` (sampling, network input normalisation, IK answers);
        measured values outside it are valid (the FK is 2π-periodic): the dataset readers wrap them
        into it and the joint checks accept them."""
        names = self.independent_joint_names
        cont = set((self.urdf or {}).get("continuous", "").split())
        if not cont or names is None:
            return np.zeros(self.dof, dtype=bool)
        return np.array([n in cont for n in names], dtype=bool)

    def expansion(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(index (n_chain,) into the independent joints, multiplier (n_chain,), offset (n_chain,))``:
        ``q_chain = multiplier · q[:, index] + offset``; None without mimic joints."""
        if self.mimic is None:
            return None
        pos = np.full(self.n_chain, -1, dtype=np.int64)
        pos[self.independent] = np.arange(self.dof)
        lead = self.mimic[:, 0].astype(np.int64)
        idx = np.where(lead < 0, pos, pos[np.maximum(lead, 0)])
        mult = np.where(lead < 0, 1.0, self.mimic[:, 1])
        off = np.where(lead < 0, 0.0, self.mimic[:, 2])
        return idx, mult, off

    @property
    def limits(self) -> np.ndarray:
        """``(n, 2)`` joint limits ``[lower, upper]``."""
        return np.stack([self.lower, self.upper], axis=1)

    @property
    def has_compliance(self) -> bool:
        """True when any joint has finite stiffness."""
        return bool(np.any(np.isfinite(self.stiffness_nm_per_rad)))

    def copy(self, **changes) -> Robot:
        """Deep copy with optional field changes (``dataclasses.replace`` semantics)."""
        new = replace(self, **changes)
        new.__post_init__()  # re-copies arrays so the copy shares no memory
        return new

    def random_joints(self, n: int, rng: np.random.Generator | int | None = None, margin: float = 0.0) -> np.ndarray:
        """``(n, dof)`` joints uniform within limits shrunk by ``margin`` (fraction of each range)."""
        rng = np.random.default_rng(rng)
        span = self.upper - self.lower
        lo, hi = self.lower + margin * span, self.upper - margin * span
        return lo + rng.random((n, self.dof)) * (hi - lo)

    def within_limits(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """``(N,)`` bool: every joint of each row within limits (with tolerance)."""
        q = np.atleast_2d(q)
        return np.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)


def robot_reach_m(robot: Robot) -> float:
    """Upper bound of the distance from the robot base to the TCP (m): link lengths plus tool."""
    links = np.hypot(robot.a_m, robot.d_m) + np.linalg.norm(robot.origin_xyz_m, axis=1)
    pris = np.array([t == "prismatic" for t in robot.joint_type])
    lo, hi = robot.lower, robot.upper
    ex = robot.expansion()
    if ex is not None:  # chain-joint strokes of mimic joints from their leaders' limits
        idx, mult, off = ex
        lo, hi = mult * lo[idx] + off, mult * hi[idx] + off
    stroke = np.where(pris, np.maximum(np.abs(lo), np.abs(hi)), 0.0)
    return float(links.sum() + stroke.sum() + np.linalg.norm(robot.tool[:3, 3]))


# --------------------------------------------------------------------------- DH <-> MDH


def dh_to_mdh(robot: Robot) -> Robot:
    """Exact conversion of a standard-DH robot to modified DH (same FK, same base/tool).

    Standard DH products ``Rz(θi)Tz(di)Tx(ai)Rx(αi)`` regroup as MDH joints with
    ``α'_i = α_{i-1}, a'_i = a_{i-1}`` (``α'_1 = a'_1 = 0``); the last ``Tx(a_n)Rx(α_n)`` moves into the
    tool. Mass properties are re-expressed in the new link frames. Requires ``beta == 0``.
    """
    if robot.convention != "dh":
        raise ValueError("dh_to_mdh: robot is not standard DH")
    if np.any(robot.beta_rad != 0):
        raise ValueError("dh_to_mdh: exact only for beta == 0")
    n = robot.dof
    a = np.concatenate([[0.0], robot.a_m[:-1]])
    al = np.concatenate([[0.0], robot.alpha_rad[:-1]])
    tail = se3.trans(robot.a_m[-1]) @ se3.rotx(robot.alpha_rad[-1])
    # Old link frame i = new frame i · Tx(a_i) Rx(α_i); COM maps through that transform.
    com = np.empty((n, 3))
    for i in range(n):
        Tfix = se3.trans(robot.a_m[i]) @ se3.rotx(robot.alpha_rad[i])
        com[i] = (Tfix @ np.append(robot.com_m[i], 1.0))[:3]
    return robot.copy(
        convention="mdh", a_m=a, alpha_rad=al, tool=tail @ robot.tool, com_m=com, name=robot.name
    )


def mdh_to_dh(robot: Robot) -> Robot:
    """Exact conversion of a modified-DH robot to standard DH (same FK, same base/tool).

    Inverse of :func:`dh_to_mdh`: ``a_i = a'_{i+1}, α_i = α'_{i+1}`` with the last pair zero, and the
    first ``Rx(α'_1)Tx(a'_1)`` moved into the base.
    """
    if robot.convention != "mdh":
        raise ValueError("mdh_to_dh: robot is not modified DH")
    if np.any(robot.beta_rad != 0):
        raise ValueError("mdh_to_dh: exact only for beta == 0")
    n = robot.dof
    a = np.concatenate([robot.a_m[1:], [0.0]])
    al = np.concatenate([robot.alpha_rad[1:], [0.0]])
    head = se3.rotx(robot.alpha_rad[0]) @ se3.trans(robot.a_m[0])
    com = np.empty((n, 3))
    for i in range(n):
        Tfix = se3.invert(se3.trans(a[i]) @ se3.rotx(al[i]))
        com[i] = (Tfix @ np.append(robot.com_m[i], 1.0))[:3]
    return robot.copy(convention="dh", a_m=a, alpha_rad=al, base=robot.base @ head, com_m=com, name=robot.name)
