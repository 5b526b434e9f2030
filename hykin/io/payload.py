"""Payload per row: dataset columns, validation, the payload fade of hybrid models.

A dataset may carry, per row, the mass at the TCP ``payload_kg`` (kg) and optionally its centre of
mass ``payload_com_x``, ``payload_com_y``, ``payload_com_z`` (m, tool frame; default the TCP). They
are plain extra columns of :class:`hykin.io.dataset.Dataset`; :func:`payload_of` reads and validates
them. Without them every function behaves as before: the payload is the robot file's
(``Robot.payload_kg``, at the TCP).

The physics carries the payload (:mod:`hykin.kinematics.compliance`: gravity torques of link masses and the
per-row payload, deflection ``C tau``, stiffness identified by :func:`hykin.calibration.calibrate.calibrate`
from the per-row torques); a hybrid model's networks learn what remains. With several payloads in
the training data the networks also take the payload as an input (:func:`payload_column`), clamped
to the trained range (:class:`PayloadRange`), so outside it only the physics changes with payload
(:mod:`hykin.hybrid`, "Payload"; figures in benchmarks/bench_payload.py). Lumped gravity
parameters for robots whose masses are unknown are not identified: the robot file's masses and
centres of mass are used as given (the identified stiffness absorbs a common scale error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics.robot import Robot

__all__ = [
    "PAYLOAD_COLUMNS",
    "PayloadRange",
    "errors_per_payload",
    "format_payload_table",
    "model_with_payload",
    "payload_column",
    "payload_from_columns",
    "payload_groups",
    "payload_kwargs",
    "payload_of",
    "payload_outside",
    "payload_range_of",
    "robot_with_payload",
    "with_payload",
]

PAYLOAD_COLUMNS = ("payload_kg", "payload_com_x", "payload_com_y", "payload_com_z")
_COM_COLUMNS = PAYLOAD_COLUMNS[1:]


class PayloadError(ValueError):
    """Bad payload input (negative or non-finite mass, partial centre-of-mass columns, shapes)."""


def _where(data) -> str:
    return getattr(data, "source", "") or "<dataset>"


MAX_PAYLOAD_KG = 3000.0  # above any serial robot's rated payload (the largest carry 2.3 t): grams, not kg
MAX_COM_M = 3.0  # a payload's centre of mass this far from the TCP: mm, not m


def _not_numeric(where: str, values):
    """The first cell of column payload_kg that is not a number, named by its data row (an error path)."""
    from .dataset import DatasetError

    for r, v in enumerate(np.asarray(values, dtype=object).reshape(-1)):
        try:
            float(v)
        except (TypeError, ValueError):
            what = "an empty cell" if str(v).strip() == "" else f"{str(v)!r} is not a number"
            return DatasetError(f"{where}, row {r + 1}, column 'payload_kg': {what} (every row needs its payload in kg, "
                                "0 without one)", file=where, row=r + 1, column="payload_kg")
    return DatasetError(f"{where}: column 'payload_kg': not numeric", file=where, column="payload_kg")


def payload_of(data, payload_kg=None, payload_com_m=None, n_rows: int | None = None):
    """Per-row payload of ``data``: ``(kg (N,), com (N, 3) m tool frame or None)``, or None.

    Explicit ``payload_kg`` (scalar or ``(N,)``) / ``payload_com_m`` (``(3,)`` or ``(N, 3)``) win;
    otherwise the dataset's columns :data:`PAYLOAD_COLUMNS` (``data.extra``). None when neither is
    given: the robot's own payload applies. Errors (:class:`hykin.io.dataset.DatasetError`) name the
    file, row and column: negative or non-finite mass, centre-of-mass columns without
    ``payload_kg`` or only some of the three.
    """
    from .dataset import DatasetError

    extra = getattr(data, "extra", None) or {}
    N = int(n_rows) if n_rows is not None else len(np.asarray(data.q))
    where = _where(data)
    kg = payload_kg
    com = payload_com_m
    if kg is None and "payload_kg" in extra:
        kg = extra["payload_kg"]
    if com is None and any(c in extra for c in _COM_COLUMNS):
        missing = [c for c in _COM_COLUMNS if c not in extra]
        if missing:
            raise DatasetError(f"{where}: column '{missing[0]}' missing: give all of {', '.join(_COM_COLUMNS)} "
                               "(payload centre of mass, m, tool frame) or none", file=where, column=missing[0])
        com = np.stack([np.asarray(extra[c], dtype=np.float64) for c in _COM_COLUMNS], 1)
    if kg is None:
        if com is not None:
            raise DatasetError(f"{where}: payload centre of mass given without column 'payload_kg'", file=where,
                               column="payload_kg")
        return None
    try:
        kg = np.asarray(kg, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _not_numeric(where, kg) from None
    kg = np.full(N, float(kg[0])) if kg.size == 1 else kg
    if kg.shape != (N,):
        raise DatasetError(f"{where}: payload_kg has {kg.size} values for {N} rows", file=where, column="payload_kg")
    bad = ~(np.isfinite(kg) & (kg >= 0))
    if bad.any():
        r = int(np.argmax(bad))
        raise DatasetError(f"{where}, row {r + 1}, column 'payload_kg': {float(kg[r])!r} is not a mass >= 0 kg", file=where,
                           row=r + 1, column="payload_kg")
    if kg.max() > MAX_PAYLOAD_KG:  # the largest serial robots carry 2.3 t
        r = int(np.argmax(kg))
        raise DatasetError(f"{where}, row {r + 1}, column 'payload_kg': {float(kg[r]):g} kg, more than any serial robot "
                           f"carries ({MAX_PAYLOAD_KG:g} kg): the values look like grams (payload_kg is in kg)",
                           file=where, row=r + 1, column="payload_kg")
    if com is not None:
        com = np.asarray(com, dtype=np.float64)
        com = np.broadcast_to(com.reshape(1, 3), (N, 3)).copy() if com.size == 3 else com
        if com.shape != (N, 3):
            raise DatasetError(f"{where}: payload centre of mass must be (3,) or ({N}, 3), got {com.shape}", file=where)
        bad = ~np.isfinite(com)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise DatasetError(f"{where}, row {r + 1}, column '{_COM_COLUMNS[c]}': non-finite centre of mass",
                               file=where, row=int(r) + 1, column=_COM_COLUMNS[c])
        far = np.linalg.norm(com, axis=1) > MAX_COM_M
        if far.any():
            r = int(np.argmax(far))
            raise DatasetError(f"{where}, row {r + 1}, columns {', '.join(_COM_COLUMNS)}: a centre of mass "
                               f"{np.linalg.norm(com[r]):.4g} m from the TCP (at most {MAX_COM_M:g} m on any tool): the values "
                               "look like mm (payload_com_* are in m)", file=where, row=r + 1, column=_COM_COLUMNS[0])
        if not np.any(com):
            com = None  # all at the TCP: the same as no column
    return kg, com


def payload_from_columns(extra: dict, n_rows: int, where: str, payload_kg=None):
    """:func:`payload_of` for the extra columns ``extra`` of a file ``where`` (CLI inputs), with a
    ``payload_kg`` option (one value for a file without the column; both at once is an error)."""
    from types import SimpleNamespace

    from .dataset import DatasetError

    if payload_kg is not None and "payload_kg" in extra:
        raise DatasetError(f"{where}: column 'payload_kg' and the option --payload-kg both give the payload; drop one",
                           file=where, column="payload_kg")
    if payload_kg is not None and not (float(payload_kg) >= 0 and float(payload_kg) < float("inf")):
        raise DatasetError(f"--payload-kg must be a finite mass >= 0 kg, got {payload_kg}")
    return payload_of(SimpleNamespace(extra=extra, source=where), payload_kg, n_rows=n_rows)


def model_with_payload(model, payload_kg: float, payload_com_m=None):
    """Shallow copy of a fitted hybrid model whose calibrated robot carries one payload
    (:func:`robot_with_payload`): for code that calls ``predict``/``predict_torch`` without payload
    arguments (hybrid IK)."""
    import copy

    m = copy.copy(model)
    m.robot_ = robot_with_payload(model.robot_, payload_kg, payload_com_m)
    m.payload_default_kg_ = float(payload_kg)  # what payload-input networks see
    return m


def payload_kwargs(payload, rows=slice(None)) -> dict:
    """Keyword arguments ``payload_kg`` / ``payload_com_m`` of the compliance and hybrid functions for
    a :func:`payload_of` result (rows ``rows``); ``{}`` for None."""
    if payload is None:
        return {}
    kg, com = payload
    return {"payload_kg": kg[rows], "payload_com_m": None if com is None else com[rows]}


def with_payload(ds, payload_kg, payload_com_m=None):
    """Copy of dataset ``ds`` with the payload columns set (``payload_kg`` scalar or ``(N,)``;
    ``payload_com_m`` ``(3,)`` or ``(N, 3)``, m, tool frame; omitted when None)."""
    from .dataset import Dataset

    N = len(ds.q)
    pl = payload_of(Dataset(q=ds.q, xyz_m=ds.xyz_m, source=ds.source), payload_kg, payload_com_m, n_rows=N)
    extra = {k: v for k, v in ds.extra.items() if k not in PAYLOAD_COLUMNS}
    extra["payload_kg"] = pl[0]
    if payload_com_m is not None:
        com = np.broadcast_to(np.asarray(payload_com_m, dtype=np.float64).reshape(-1, 3), (N, 3))
        for j, c in enumerate(_COM_COLUMNS):
            extra[c] = com[:, j].copy()
    return Dataset(q=ds.q, xyz_m=ds.xyz_m, quat_wxyz=ds.quat_wxyz, extra=extra, source=ds.source)


def robot_with_payload(robot: Robot, payload_kg: float, payload_com_m=None) -> Robot:
    """``robot`` carrying one payload: ``payload_kg`` at the TCP, or, with a centre of mass
    ``payload_com_m`` (3,) (m, tool frame) off the TCP, as a point mass merged into the last link
    (same gravity torques: the point is fixed in the last link's frame)."""
    kg = float(payload_kg)
    if not (np.isfinite(kg) and kg >= 0):
        raise PayloadError(f"payload_kg must be a finite mass >= 0 kg, got {payload_kg!r}")
    if payload_com_m is None or not np.any(payload_com_m):
        return robot.copy(payload_kg=kg)
    from ..kinematics.chain import chain_of

    com = np.asarray(payload_com_m, dtype=np.float64).reshape(3)
    ch = chain_of(robot)
    tool = np.asarray(ch.tool, dtype=np.float64)
    p_link = tool[:3, :3] @ com + tool[:3, 3]  # in the last link's frame (the flange; TCP = flange · tool)
    m, c = robot.mass_kg.copy(), robot.com_m.copy()
    total = m[-1] + kg
    if total > 0:
        c[-1] = (m[-1] * c[-1] + kg * p_link) / total
    m[-1] = total
    return robot.copy(mass_kg=m, com_m=c, payload_kg=0.0)


@dataclass
class PayloadRange:
    """Payloads a model was trained on: ``lower_kg``/``upper_kg`` and up to 32 distinct ``values_kg``."""

    lower_kg: float
    upper_kg: float
    values_kg: list

    def to_dict(self) -> dict:
        return {"lower_kg": self.lower_kg, "upper_kg": self.upper_kg, "values_kg": list(self.values_kg)}

    @classmethod
    def from_dict(cls, d: dict) -> PayloadRange:
        return cls(float(d["lower_kg"]), float(d["upper_kg"]), [float(v) for v in d.get("values_kg", [])])


def payload_column(qn, payload_kg, rng: PayloadRange):
    """``qn`` ``(N, k)`` (numpy or torch) with the payload appended as column ``k``, clamped to the
    trained range ``rng`` (a network with payload as input never sees a payload it was not trained on)."""
    N = qn.shape[0]
    lo, hi = rng.lower_kg, rng.upper_kg
    if hasattr(qn, "detach"):  # torch
        import torch

        kg = torch.as_tensor(payload_kg, dtype=qn.dtype, device=qn.device).reshape(-1)
        kg = torch.clamp(kg.expand(N) if kg.numel() == 1 else kg, lo, hi)
        return torch.cat([qn, kg[:, None]], 1)
    kg = np.asarray(payload_kg, dtype=np.float64).reshape(-1)
    kg = np.clip(np.broadcast_to(kg, (N,)) if kg.size == 1 else kg, lo, hi)
    return np.concatenate([qn, kg[:, None].astype(qn.dtype)], 1)


def payload_range_of(kg: np.ndarray) -> PayloadRange:
    """:class:`PayloadRange` of per-row payloads ``kg`` ``(N,)``."""
    kg = np.asarray(kg, dtype=np.float64)
    vals = np.unique(np.round(kg, 6))
    return PayloadRange(float(kg.min()), float(kg.max()), vals[:32].tolist())


def payload_groups(payload) -> list[tuple[np.ndarray, float, np.ndarray | None]]:
    """``[(row indices, kg, com (3,) m or None)]``: the rows of each distinct (mass, centre of mass) of a
    per-row ``payload`` ``(kg (N,), com (N, 3) or None)`` (:func:`payload_of`), for one solve per load."""
    kg, com = payload
    key = np.column_stack([kg, np.zeros((len(kg), 3)) if com is None else com])
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    return [(np.flatnonzero(inv == u), float(uniq[u, 0]), None if com is None else uniq[u, 1:]) for u in range(len(uniq))]


def payload_outside(rng: PayloadRange | None, kg, tol_kg: float = 1e-6) -> np.ndarray:
    """``(N,)`` bool: payloads ``kg`` outside the trained range ``rng`` (False for ``rng=None``)."""
    kg = np.atleast_1d(np.asarray(kg, dtype=np.float64))
    if rng is None:
        return np.zeros(kg.shape, dtype=bool)
    return (kg < rng.lower_kg - tol_kg) | (kg > rng.upper_kg + tol_kg)


def errors_per_payload(kg, errors: dict) -> dict:
    """Mean / p95 / max error per distinct payload.

    ``kg``: ``(N,)`` payload per row. ``errors``: name -> ``(pos_mm (N,), ang_deg (N,) or None)``.
    Returns ``{payload_kg: {name: {"n", "pos_mean_mm", "pos_p95_mm", "pos_max_mm"[, "rot_mean_deg", ...]}}}``
    in increasing payload (payloads rounded to 1 g)."""
    kg = np.round(np.asarray(kg, dtype=np.float64), 3)
    out = {}
    for v in np.unique(kg):
        sel = kg == v
        row = {}
        for name, (p, a) in errors.items():
            d = {"n": int(sel.sum()), "pos_mean_mm": float(np.mean(p[sel])), "pos_p95_mm": float(np.percentile(p[sel], 95)),
                 "pos_max_mm": float(np.max(p[sel]))}
            if a is not None:
                d.update(rot_mean_deg=float(np.mean(a[sel])), rot_p95_deg=float(np.percentile(a[sel], 95)),
                         rot_max_deg=float(np.max(a[sel])))
            row[name] = d
        out[float(v)] = row
    return out


def format_payload_table(per_payload: dict) -> str:
    """Text table of :func:`errors_per_payload` (mm, deg)."""
    lines = [f"{'payload kg':>10} {'model':<11} {'n':>6} {'pos mean mm':>12} {'pos p95 mm':>11} {'rot mean deg':>13}"]
    for v, row in per_payload.items():
        for name, d in row.items():
            rot = f"{d['rot_mean_deg']:13.4f}" if "rot_mean_deg" in d else f"{'-':>13}"
            lines.append(f"{v:10.3f} {name:<11} {d['n']:6d} {d['pos_mean_mm']:12.4f} {d['pos_p95_mm']:11.4f} {rot}")
    return "\n".join(lines)
