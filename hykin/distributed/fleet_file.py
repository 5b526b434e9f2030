"""The fleet file (FLEET.toml, issue #29): one ``[[robot]]`` entry per robot; paths relative to the file.

```toml
[resources]                 # optional
cpus_per_robot = 1
gpus_per_robot = 0
[[robot]]
name = "cell-3"             # letters, digits, . _ -; unique ignoring case; names the output files
                            # (cell-3.hykin, cell-3-registered.hykin: no other name may be "cell-3-registered")
robot = "cell3.toml"        # a robot file or preset name
train = "cell3_train.csv"
test = "cell3_test.csv"     # optional
register = "cell3_day2.csv" # optional: a new series, registered from `poses` of its rows
poses = 30                  # optional (30)
length_unit = "m"           # optional: units of this robot's data files: x, y, z in m or mm, joints in rad or deg
angle_unit = "rad"          #   (as `hykin fit --length-unit / --angle-unit`; the robot file declares its own)
[robot.fit]                 # optional `hykin fit` options (names with underscores)
min_steps = 5000
```

:func:`read_fleet` -> :class:`FleetSpec` (SpecError, one line naming the file, the entry and the key).
``[robot.fit]`` values are checked by the sweep's checker (:func:`hykin.distributed.options.check_option`:
types, architecture / recipe / device names), so a fleet refuses what a sweep refuses, before Ray starts.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from ..hybrid.fit_options import FIT_OPTIONS
from .files import SpecError, check_keys, read_toml, rel_path, robot_spec
from .options import check_option, data_units

__all__ = ["FleetRobot", "FleetSpec", "read_fleet"]

ROBOT_KEYS = ("name", "robot", "train", "test", "register", "poses", "length_unit", "angle_unit", "fit")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


@dataclass
class FleetRobot:
    """One robot of a fleet: absolute paths (``test``/``register`` None when not given), fit options, the
    units of its data files (``length_unit`` m/mm, ``angle_unit`` rad/deg, as `hykin fit`)."""

    name: str
    robot: str
    train: Path
    test: Path | None = None
    register: Path | None = None
    poses: int = 30
    fit: dict = field(default_factory=dict)
    length_unit: str = "m"
    angle_unit: str = "rad"


@dataclass
class FleetSpec:
    """A parsed fleet file."""

    path: Path
    robots: list
    cpus_per_robot: float = 1.0
    gpus_per_robot: float = 0.0


def _check_outputs(p: Path, i: int, name: str, outputs: dict) -> None:
    """SpecError (one line naming both entries) when robot #``i`` ``name`` would write a model file another
    entry writes: ``NAME.hykin`` and ``NAME-registered.hykin`` are each robot's, compared ignoring case
    (case-insensitive file systems), so no name may equal another's, nor another's NAME-registered."""
    for fname in (f"{name}.hykin", f"{name}-registered.hykin"):
        other = outputs.get(fname.lower())
        if other is not None:
            j, oname = other
            raise SpecError(f"{p}: [[robot]] #{i} name = {name!r} and [[robot]] #{j} name = {oname!r} would both write "
                            f"{fname} (names must differ ignoring case, and no name may be another's NAME-registered: "
                            "that is its registered model's file)")
    for fname in (f"{name}.hykin", f"{name}-registered.hykin"):
        outputs[fname.lower()] = (i, name)


def _fit_options(p: Path, where: str, fit) -> dict:
    """The ``[robot.fit]`` table of the entry ``where``, checked as a sweep's ``[grid]`` values are
    (:func:`hykin.distributed.options.check_option`: names, types, architectures, recipes, devices)."""
    if not isinstance(fit, dict):
        raise SpecError(f"{p}: {where}fit must be a table [robot.fit]")
    for k in ("length_unit", "angle_unit"):
        if k in fit:
            raise SpecError(f"{p}: {where}[robot.fit] {k}: the data units are keys of the [[robot]] entry, not of "
                            f"[robot.fit] (move {k} = {fit[k]!r} above [robot.fit])")
    check_keys(p, where + "[robot.fit] ", fit, FIT_OPTIONS)
    for k, v in fit.items():
        check_option(p, where + "[robot.fit] ", k, v)
    return dict(fit)


def read_fleet(path: str | Path) -> FleetSpec:
    """Parse and check the fleet file ``path`` (SpecError naming the file, entry and key on a mistake)."""
    p, t = read_toml(path)
    check_keys(p, "", t, ("robot", "resources"))
    entries = t.get("robot")
    if not isinstance(entries, list) or not entries:
        raise SpecError(f"{p}: no [[robot]] entries (give one per robot)")
    robots, outputs = [], {}  # output name (lower case) -> (entry number, robot name) that writes it
    for i, e in enumerate(entries, 1):
        where = f"[[robot]] #{i} "
        if not isinstance(e, dict):
            raise SpecError(f"{p}: {where}must be a table")
        check_keys(p, where, e, ROBOT_KEYS)
        name = e.get("name")
        if not isinstance(name, str) or not _NAME.match(name):
            raise SpecError(f"{p}: {where}name = {name!r}: expected letters, digits, '.', '_' or '-' (it names the output files)")
        _check_outputs(p, i, name, outputs)
        where = f"[[robot]] {name!r} "
        fit = _fit_options(p, where, e.get("fit", {}))
        length_unit, angle_unit = data_units(p, where, e)
        poses = e.get("poses", 30)
        if isinstance(poses, bool) or not isinstance(poses, int) or poses < 3:
            raise SpecError(f"{p}: {where}poses = {poses!r}: expected an integer >= 3")
        robots.append(FleetRobot(
            name=name, robot=robot_spec(p, where + "robot", e.get("robot")),
            train=rel_path(p, where + "train", e.get("train")),
            test=rel_path(p, where + "test", e.get("test"), optional=True),
            register=rel_path(p, where + "register", e.get("register"), optional=True), poses=poses, fit=fit,
            length_unit=length_unit, angle_unit=angle_unit))
    res = t.get("resources", {})
    check_keys(p, "[resources] ", res, ("cpus_per_robot", "gpus_per_robot"))
    vals = {k: res.get(k, d) for k, d in (("cpus_per_robot", 1), ("gpus_per_robot", 0))}
    for k, v in vals.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0:
            raise SpecError(f"{p}: [resources] {k} = {v!r}: expected a number >= 0")
    return FleetSpec(path=p, robots=robots, cpus_per_robot=float(vals["cpus_per_robot"]),
                     gpus_per_robot=float(vals["gpus_per_robot"]))
