"""Several reflectors measured at the same joints: the columns ``x2,y2,z2``, ``x3,y3,z3`` ... (DESIGN.md §3).

The first point is the dataset's ``x,y,z`` (the TCP); further points are extra columns, kept by
:func:`hykin.io.dataset_files.read_dataset` in :attr:`Dataset.extra` as read. :func:`reflector_points`
stacks them ``(N, K, 3)``; :func:`hykin.calibration.calibrate.calibrate` then fits every reflector as a point
on the same tool body (each with its own unknown offset).
"""

from __future__ import annotations

import numpy as np

__all__ = ["reflector_columns", "reflector_points", "with_reflector_unit"]


def reflector_columns(ds) -> list[tuple[str, str, str]]:
    """``[("x2", "y2", "z2"), ...]``: the further reflectors' column triples present in ``ds.extra``
    (consecutive from 2). A partial triple raises ValueError naming the missing column."""
    extra = getattr(ds, "extra", None) or {}
    out = []
    k = 2
    while any(f"{c}{k}" in extra for c in "xyz"):
        names = tuple(f"{c}{k}" for c in "xyz")
        missing = [n for n in names if n not in extra]
        if missing:
            raise ValueError(f"{getattr(ds, 'source', '') or 'dataset'}: column '{missing[0]}' is missing "
                             f"(reflector {k} needs {', '.join(names)})")
        out.append(names)
        k += 1
    return out


def reflector_points(ds) -> np.ndarray:
    """All measured points ``(N, K, 3)`` (m): ``x,y,z`` then ``x2,y2,z2`` ... (``K = 1`` without extras)."""
    pts = [np.asarray(ds.xyz_m, dtype=np.float64)]
    for names in reflector_columns(ds):
        cols = []
        for n in names:
            v = ds.extra[n]
            if v.dtype.kind not in "fiu":
                raise ValueError(f"{getattr(ds, 'source', '') or 'dataset'}: column '{n}' is not numeric")
            cols.append(np.asarray(v, dtype=np.float64))
        pts.append(np.stack(cols, 1))
    return np.stack(pts, 1)


def with_reflector_unit(ds, length_unit: str):
    """``ds`` with the further reflectors' columns converted from ``length_unit`` to metres (called by
    :func:`hykin.io.dataset_files.read_dataset`, which converts ``x,y,z`` the same way)."""
    f = {"m": 1.0, "mm": 1e-3}[length_unit]
    if f == 1.0:
        return ds
    for names in reflector_columns(ds):
        for n in names:
            ds.extra[n] = np.asarray(ds.extra[n], dtype=np.float64) * f
    return ds
