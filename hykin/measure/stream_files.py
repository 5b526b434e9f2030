"""The two files of a dynamic collection in the plain layout, read fast and in bounded memory.

A robot joint log (time column and joints) and a tracker stream (time column, positions, optionally
a quaternion) written as comma-separated CSV with one header line or as Parquet — what
``hykin simulate --stream`` writes and what most loggers can export — are read column by column in
chunks (:func:`hykin.io.stream_columns.read_columns`). Other layouts go through a mapping file and
:func:`hykin.measure.table_import.read_mapped`.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..io.dataset import DatasetError
from ..io.stream_columns import header_of, read_columns
from .table_map import ANGLE_UNITS_RAD, LENGTH_UNITS_M, TIME_UNITS_S

__all__ = ["plain_layout", "read_robot_log", "read_tracker_stream"]


def plain_layout(path: str | Path) -> bool:
    """Whether ``path`` is Parquet or a comma-separated CSV whose header names plain columns."""
    p = Path(path)
    if p.suffix.lower() == ".parquet":
        return True
    if p.suffix.lower() != ".csv" or not p.is_file():
        return False
    head = header_of(p)
    return len(head) >= 2 and all(re.fullmatch(r"[A-Za-z_][\w.]*", c) for c in head)


def read_robot_log(path, *, dof: int, revolute, time: str = "t", angle_unit: str = "rad", length_unit: str = "m",
                   time_unit: str = "s") -> tuple[np.ndarray, np.ndarray]:
    """``(t_s (M,), q (M, dof))`` from a plain robot log with joints ``q1..q<dof>``."""
    names = [f"q{j + 1}" for j in range(dof)]
    c = read_columns(path, [time, *names])
    scale = np.where(np.asarray(revolute, bool), ANGLE_UNITS_RAD[angle_unit], LENGTH_UNITS_M[length_unit])
    q = np.stack([c[n] for n in names], axis=1) * scale
    return c[time] * TIME_UNITS_S[time_unit], q


def read_tracker_stream(path, *, time: str = "t", position=("x", "y", "z"), quaternion=None, length_unit: str = "m",
                        time_unit: str = "s") -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(t_s (K,), xyz_m (K, 3), quat_wxyz (K, 4) | None)`` from a plain tracker stream; empty or
    ``nan`` position cells are NaN (beam lost)."""
    pos = list(position)
    quat = list(quaternion) if quaternion else []
    if len(pos) != 3 or (quat and len(quat) != 4):
        raise DatasetError(f"{path}: expected 3 position columns and 0 or 4 quaternion columns", file=str(path))
    c = read_columns(path, [time, *pos, *quat], allow_missing=set(pos) | set(quat))
    xyz = np.stack([c[n] for n in pos], axis=1) * LENGTH_UNITS_M[length_unit]
    qt = np.stack([c[n] for n in quat], axis=1) if quat else None
    return c[time] * TIME_UNITS_S[time_unit], xyz, qt
