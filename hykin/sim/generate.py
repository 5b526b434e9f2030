"""Simulated dataset files: a virtual robot's measurements written to a data file, with its truth
file beside it (:func:`simulate_to_file`, the ``hykin simulate`` command).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..io.dataset import concat
from ..io.dataset_files import write_dataset
from .presets import virtual_preset
from .sampling import iso_cube, sample
from .simulate import (
    SimulationError,
    VirtualRobot,
    load_truth,
    save_truth,
    simulate,
    truth_path_for,
)

__all__ = ["simulate_to_file"]


def simulate_to_file(preset, n: int, out_path, plan: str = "uniform", seed: int = 0, noise: bool = True,
                     progress: Callable[[int, int], None] | None = None, chunk: int = 50_000,
                     payloads=None) -> str:
    """Sample ``n`` joints with ``plan`` (hykin.sampling), simulate them in chunks, write the dataset
    to ``out_path`` (.csv/.parquet) and the truth beside it (``*.truth.json``); returns the truth path.

    ``preset``: a preset name, a :class:`VirtualRobot` or a truth file (.json). ``seed`` seeds the
    preset's deviations, the plan and the noise: same arguments, same files. ``progress(done, total)``
    is called after each chunk; the data do not depend on ``chunk``. With ``plan="iso_cube"`` the pose label (1..5) is kept as column
    ``pose``; a ``sample`` column holds the sample index (the time axis of thermal drift).
    ``payloads``: payload masses (kg) to draw the data at (row ``i`` carries ``payloads[i % k]``,
    at the TCP), kept as column ``payload_kg``; default: the preset's payload, no column.
    """
    if isinstance(preset, VirtualRobot):
        vr = preset
    elif str(preset).lower().endswith(".json"):
        vr = load_truth(preset)
    else:
        vr = virtual_preset(str(preset), seed=seed)
    n = int(n)
    if n < 1:
        raise SimulationError(f"number of samples must be >= 1, got {n}")
    plan_name = str(plan).replace("-", "_").lower()
    rng_plan = np.random.default_rng([seed, 7])
    rng_noise = np.random.default_rng([seed, 11])
    extra_all: dict[str, np.ndarray] = {}
    if plan_name == "iso_cube":
        p = iso_cube(vr.nominal, cycles=-(-n // 5), rng=rng_plan)
        q, extra_all["pose"] = p.q[:n], p.labels[:n]
    else:
        q = sample(plan_name, vr.nominal, n, rng_plan)
    kg = None
    if payloads is not None:
        pl = np.asarray(payloads, dtype=np.float64).reshape(-1)
        if pl.size == 0 or not np.all(np.isfinite(pl) & (pl >= 0)):
            raise SimulationError(f"payloads must be masses >= 0 kg, got {list(pl)}")
        kg = np.resize(pl, n)
    parts = []
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        ds = simulate(vr, q[s:e], noise=noise, rng=rng_noise, start_index=s, payload_kg=None if kg is None else kg[s:e])
        ds.extra["sample"] = np.arange(s, e)
        for k, v in extra_all.items():
            ds.extra[k] = v[s:e]
        parts.append(ds)
        if progress is not None:
            progress(e, n)
    data = parts[0] if len(parts) == 1 else concat(parts)
    data.source = f"hykin simulate {vr.name} -n {n} --plan {plan_name} --seed {seed}" + ("" if noise else " --no-noise") + (
        "" if payloads is None else " --payloads " + ",".join(f"{v:g}" for v in np.asarray(payloads).reshape(-1)))
    write_dataset(data, out_path)
    return str(save_truth(vr, truth_path_for(out_path)))
