"""The sweep file (SWEEP.toml, DESIGN of issue #29): one dataset, one test set, a grid of fit options.

```toml
robot = "robot.toml"        # a file relative to this one, or a preset name
train = "train.csv"         # relative to this file
test = "test.csv"
length_unit = "m"           # optional: units of the train/test files' x, y, z (m, mm) and joints (rad, deg),
angle_unit = "rad"          #   as `hykin fit --length-unit / --angle-unit`
subsample_seed = 0          # optional: the permutation the nested n_train subsets are prefixes of
[grid]                      # `hykin fit` option names with underscores, plus n_train; every combination is a trial
arch = ["default", "D1"]
seed = [0, 1]
min_steps = [2000]
n_train = [1000, 4000]      # optional: nested subsets of train (the first n of one fixed permutation)
[random]                    # optional: `samples` draws of these keys for each grid combination
samples = 4
seed = 0                    # the seed of the random draws (one int); the fits' seeds go in [grid] seed = [...]
lr_key = ...                # a list (uniform choice) or {uniform = [lo, hi]} / {loguniform = [lo, hi]}
[resources]
cpus_per_trial = 1
gpus_per_trial = 0
```

Several grids: ``[[grid]]`` tables instead of one ``[grid]``; the trials are those of each grid, in order
(e.g. the paper's architectures with the paper recipe, plus hykin's default with its own).

:func:`read_sweep` -> :class:`SweepSpec` (SpecError, one line naming the file and key, on any mistake);
:meth:`SweepSpec.trials` -> the list of trial option dicts, in a fixed order.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from ..hybrid.fit_options import FIT_OPTIONS
from .files import SpecError, check_keys, inputs_sha256, read_toml, rel_path, robot_spec
from .options import OPTION_TYPES, check_option, data_units, units_options

__all__ = ["SWEEP_KEYS", "SweepSpec", "read_sweep", "sweep_inputs_hash", "trial_key"]

SWEEP_KEYS = ("robot", "train", "test", "length_unit", "angle_unit", "subsample_seed", "grid", "random", "resources")
GRID_KEYS = (*FIT_OPTIONS, "n_train")


@dataclass
class SweepSpec:
    """A parsed sweep file: ``robot`` (file path or preset), ``train``/``test`` absolute paths, ``grids``
    (a list of option -> list of values), ``random`` option -> list or {uniform|loguniform: [lo, hi]},
    ``samples``/``random_seed`` for the random part, resources per trial (CPUs, GPUs), ``length_unit`` /
    ``angle_unit`` of the train and test files (read as `hykin fit --length-unit / --angle-unit`)."""

    path: Path
    robot: str
    train: Path
    test: Path
    grids: list
    random: dict = field(default_factory=dict)
    samples: int = 0
    random_seed: int = 0
    subsample_seed: int = 0
    cpus_per_trial: float = 1.0
    gpus_per_trial: float = 0.0
    length_unit: str = "m"
    angle_unit: str = "rad"

    def trials(self) -> list[dict]:
        """Every combination of each grid (last key fastest), times ``samples`` random draws when [random] is given."""
        import numpy as np

        combos = [dict(zip(g, vals)) for g in self.grids for vals in itertools.product(*g.values())]
        if not self.random:
            return combos
        rng = np.random.default_rng(self.random_seed)
        out = []
        for c in combos:
            for _ in range(self.samples):
                d = dict(c)
                for k, v in self.random.items():
                    if isinstance(v, list):
                        d[k] = v[int(rng.integers(len(v)))]
                    elif "uniform" in v:
                        d[k] = float(rng.uniform(*v["uniform"]))
                    else:
                        lo, hi = v["loguniform"]
                        d[k] = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
                    if OPTION_TYPES[k] is int:
                        d[k] = int(round(d[k]))
                out.append(d)
        return out


def trial_key(options: dict) -> str:
    """A trial's identity for resuming: its options as sorted JSON (with :func:`sweep_inputs_hash`, which
    must also be unchanged for a recorded trial to be kept)."""
    return json.dumps(options, sort_keys=True, default=str)


def sweep_inputs_hash(spec: SweepSpec) -> str:
    """SHA-256 over what every trial's result depends on besides its options
    (:func:`hykin.distributed.files.inputs_sha256`, the one used by the fleet): the robot file's bytes (a
    preset: its name), the train and test files' bytes, ``subsample_seed`` and the data units (when not m / rad)."""
    return inputs_sha256((spec.robot, spec.train, spec.test),
                         {"subsample_seed": spec.subsample_seed, **units_options(spec.length_unit, spec.angle_unit)})


def read_sweep(path: str | Path) -> SweepSpec:
    """Parse and check the sweep file ``path`` (SpecError naming the file and key on a mistake)."""
    p, t = read_toml(path)
    check_keys(p, "", t, SWEEP_KEYS)
    grids = t.get("grid", {})
    grids = [grids] if isinstance(grids, dict) else grids
    if not isinstance(grids, list) or not all(isinstance(g, dict) for g in grids):
        raise SpecError(f"{p}: grid must be a table [grid] or tables [[grid]]")
    grids = [{k: (v if isinstance(v, list) else [v]) for k, v in g.items()} for g in grids]
    for g in grids:
        check_keys(p, "[grid] ", g, GRID_KEYS)
        for k, vals in g.items():
            if not vals:
                raise SpecError(f"{p}: [grid] {k} is an empty list (give at least one value)")
            for v in vals:
                check_option(p, "[grid] ", k, v)
    grid = {k: v for g in grids for k, v in g.items()}
    rnd = dict(t.get("random", {}))
    samples, rseed = rnd.pop("samples", 1 if rnd else 0), rnd.pop("seed", 0)
    if isinstance(rseed, bool) or not isinstance(rseed, int):
        raise SpecError(f"{p}: [random] seed = {rseed!r}: [random] seed is the seed of the random draws (one "
                        "integer, e.g. seed = 0); the fits' seeds go in [grid] (e.g. [grid] seed = [0, 1])")
    if isinstance(samples, bool) or not isinstance(samples, int):
        raise SpecError(f"{p}: [random] samples = {samples!r}: expected an integer (draws per grid combination)")
    check_keys(p, "[random] ", rnd, GRID_KEYS)
    for k, v in rnd.items():
        if k in grid:
            raise SpecError(f"{p}: [random] {k} is also a [grid] key (give it in one of them)")
        _check_random(p, k, v)
    if rnd and samples < 1:
        raise SpecError(f"{p}: [random] samples = {samples}: must be >= 1")
    res = t.get("resources", {})
    check_keys(p, "[resources] ", res, ("cpus_per_trial", "gpus_per_trial"))
    cpus, gpus = res.get("cpus_per_trial", 1), res.get("gpus_per_trial", 0)
    for k, v, lo in (("cpus_per_trial", cpus, 0), ("gpus_per_trial", gpus, 0)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v < lo:
            raise SpecError(f"{p}: [resources] {k} = {v!r}: expected a number >= {lo}")
    sseed = t.get("subsample_seed", 0)
    if isinstance(sseed, bool) or not isinstance(sseed, int):
        raise SpecError(f"{p}: subsample_seed = {sseed!r}: expected an integer")
    length_unit, angle_unit = data_units(p, "", t)
    return SweepSpec(path=p, robot=robot_spec(p, "robot", t.get("robot")), train=rel_path(p, "train", t.get("train")),
                     test=rel_path(p, "test", t.get("test")), grids=grids, random=rnd, samples=samples if rnd else 0,
                     random_seed=int(rseed), subsample_seed=sseed, cpus_per_trial=float(cpus), gpus_per_trial=float(gpus),
                     length_unit=length_unit, angle_unit=angle_unit)


def _check_random(p: Path, k: str, v) -> None:
    """A ``[random]`` key: a non-empty list of valid values, or ``{uniform|loguniform = [lo, hi]}`` of a numeric
    option whose bounds are valid values (an int option's bounds rounded, as its draws are); SpecError otherwise."""
    if isinstance(v, list):
        if not v:
            raise SpecError(f"{p}: [random] {k} is an empty list")
        for x in v:
            check_option(p, "[random] ", k, x)
        return
    t = OPTION_TYPES[k]
    kind, bounds = next(iter(v.items())) if isinstance(v, dict) and len(v) == 1 else (None, None)
    numbers = isinstance(bounds, list) and len(bounds) == 2 and all(
        isinstance(b, (int, float)) and not isinstance(b, bool) for b in bounds)
    if kind not in ("uniform", "loguniform") or t not in (int, (int, float)) or not numbers:
        raise SpecError(f"{p}: [random] {k} = {v!r}: expected a list or {{uniform = [lo, hi]}} / "
                        "{loguniform = [lo, hi]} (two numbers) for a numeric option")
    if kind == "loguniform" and min(bounds) <= 0:
        raise SpecError(f"{p}: [random] {k}: loguniform bounds must be > 0, got {bounds}")
    for b in bounds:
        check_option(p, "[random] ", k, int(round(b)) if t is int else b)

