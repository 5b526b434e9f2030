"""Several stations and tools in one dataset: row groups, their frames, and the data in one frame.

A ``station`` column (any label) names the instrument placement each row was measured from; each
station has its own measurement frame ``B_s`` (station frame -> robot base, the form of the robot
file's ``[base]``). A ``tool`` column names the tool / reflector mount on the flange; each tool has its
own frame ``E_t`` (flange -> TCP). Row ``n`` of station ``s`` and tool ``t`` is modelled as
``T = B_s · chain(q) · E_t`` and all frames are fitted jointly with one robot calibration (a bundle).

**Reference.** The station with the most rows (ties: the first to appear in the file) is the
reference: its frame is the robot's own ``base`` (started at the robot file's ``[base]``, or found by
:mod:`hykin.calibration.initial_registration` for raw data), so the calibrated robot predicts in the
reference station's frame. Likewise the tool with the most rows is the robot's ``tool``. Every other
station / tool gets its own 6-D group ``station[B].x`` ... ``station[B].rz`` / ``tool[T2].x`` ...,
composed on the right like ``base`` and ``tool`` (``B ← B · E(v, w)``).

**Too few rows.** A station frame has 6 unknowns. Position-only rows fix it only with at least 3
points that are not collinear (Kabsch); 6-D rows with at least 2 rows (one 6-D row determines the
frame exactly and leaves no redundancy to check it). A tool frame is fixed, from position-only rows,
only through different flange orientations: at least 3 rows (6-D: 2). Fewer, or collinear points,
are refused with one line naming the station, its row count and what it needs
(:func:`check_groups`). Non-collinear means: the second singular value of the centred points is
above :data:`COLLINEAR_TOL_M` (1 mm RMS off the best line).

:func:`to_reference` expresses measured rows in the reference station's frame with the reference
tool, so the hybrid model's networks learn from data in one frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry import se3
from ..geometry.rigid import kabsch, nearest_rotation
from ..io.dataset import STATION_COLUMN, TOOL_COLUMN, Dataset, DatasetError, row_error, row_labels
from .result import CalibrationError

__all__ = [
    "COLLINEAR_TOL_M",
    "RowGroups",
    "StationFrames",
    "check_groups",
    "frame_starts",
    "reference_rows",
    "add_frames",
    "apply_row_transforms",
    "row_groups",
    "row_transforms",
    "series_labels",
    "to_reference",
]

COLLINEAR_TOL_M = 1e-3  # RMS distance of a station's points from their best line below which they are "on a line"


def _grouping(labels: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
    """Labels ordered reference first (most rows; ties: first to appear), and the ``(N,)`` index of each row."""
    uniq, first, inv, counts = np.unique(labels, return_index=True, return_inverse=True, return_counts=True)
    order = sorted(range(len(uniq)), key=lambda k: (-counts[k], first[k]))
    rank = np.empty(len(uniq), dtype=np.int64)
    rank[order] = np.arange(len(uniq))
    return tuple(str(uniq[k]) for k in order), rank[inv]


@dataclass(frozen=True)
class RowGroups:
    """Which station and which tool each row belongs to; index 0 is the reference of each."""

    station_labels: tuple[str, ...]
    station: np.ndarray  # (N,) int, index into station_labels
    tool_labels: tuple[str, ...]
    tool: np.ndarray  # (N,) int, index into tool_labels
    source: str = ""

    def subset(self, idx) -> RowGroups:
        return RowGroups(self.station_labels, self.station[idx], self.tool_labels, self.tool[idx], self.source)

    def rows_of(self, kind: str, k: int) -> np.ndarray:
        """``(N,)`` bool mask of the rows of station / tool ``k`` (``kind`` "station" or "tool")."""
        return (self.station if kind == "station" else self.tool) == k


def row_groups(data, n_rows: int) -> RowGroups | None:
    """Row groups of ``data`` (a Dataset or anything with ``extra``), or None when it has neither a
    ``station`` nor a ``tool`` column, or both name one label only (one frame each: the plain case)."""
    extra = getattr(data, "extra", None)
    if not extra or (STATION_COLUMN not in extra and TOOL_COLUMN not in extra):
        return None
    ds = data if isinstance(data, Dataset) else Dataset(q=np.zeros((n_rows, 0)), xyz_m=np.zeros((n_rows, 3)),
                                                        extra=dict(extra), source=getattr(data, "source", ""))
    out = []
    for col in (STATION_COLUMN, TOOL_COLUMN):
        lab = row_labels(ds, col)
        out.append((("-",), np.zeros(n_rows, np.int64)) if lab is None else _grouping(lab))
    if len(out[0][0]) == 1 and len(out[1][0]) == 1:
        return None
    return RowGroups(out[0][0], out[0][1], out[1][0], out[1][1], getattr(data, "source", "") or "<dataset>")


def check_groups(groups: RowGroups, xyz: np.ndarray, position_only: bool) -> None:
    """Refuse (one line, :class:`CalibrationError`) a station or tool with too few rows to fix its
    frame (module docstring, "Too few rows"); ``xyz`` ``(N, 3)`` or ``(N, K, 3)`` measured points, m."""
    pts = xyz if xyz.ndim == 2 else xyz[:, 0]
    need = 3 if position_only else 2
    kind_rows = "position-only rows" if position_only else "6-D rows"
    for kind, labels in (("station", groups.station_labels), ("tool", groups.tool_labels)):
        if len(labels) == 1:
            continue
        for k, lab in enumerate(labels):
            m = groups.rows_of(kind, k)
            n = int(m.sum())
            if n < need:
                raise CalibrationError(
                    f"{groups.source}: {kind} {lab!r} has {n} row{'s' if n != 1 else ''}; its {kind} frame needs at least "
                    f"{need} {kind_rows}{' with points not on a line' if position_only and kind == 'station' else ''}: "
                    f"measure more poses from it or drop its rows")
            if position_only and kind == "station":
                c = pts[m] - pts[m].mean(0)
                s = np.linalg.svd(c, compute_uv=False)
                off_line = float(s[1]) / math.sqrt(n) if len(s) > 1 else 0.0
                if off_line < COLLINEAR_TOL_M:
                    raise CalibrationError(
                        f"{groups.source}: station {lab!r} has {n} rows but its points lie on a line ({off_line * 1e3:.3g} mm "
                        f"RMS off it); a position-only station frame needs at least 3 points not on a line "
                        f"(>= {COLLINEAR_TOL_M * 1e3:g} mm RMS off it): measure poses spread in two directions")


@dataclass
class StationFrames:
    """The frames of every station and tool of a calibration (index 0: the reference, = the robot's
    ``base`` / ``tool``). station_bases ``(S, 4, 4)`` station frame -> robot base (m); tool_frames
    ``(T, 4, 4)`` flange -> TCP (m)."""

    station_labels: tuple[str, ...]
    station_bases: np.ndarray
    tool_labels: tuple[str, ...]
    tool_frames: np.ndarray

    def copy(self) -> StationFrames:
        return StationFrames(tuple(self.station_labels), self.station_bases.copy(), tuple(self.tool_labels),
                             self.tool_frames.copy())

    def synced(self, robot) -> StationFrames:
        """A copy whose reference frames are ``robot``'s base and tool."""
        out = self.copy()
        out.station_bases[0], out.tool_frames[0] = robot.base, robot.tool
        return out

    @property
    def reference_station(self) -> str:
        return self.station_labels[0]

    def base_of(self, label: str, where: str = "station") -> np.ndarray:
        """``(4, 4)`` frame of station ``label`` (ValueError naming the known ones)."""
        return self._of(label, where, "station", self.station_labels, self.station_bases)

    def tool_of(self, label: str, where: str = "tool") -> np.ndarray:
        """``(4, 4)`` frame of tool ``label`` (ValueError naming the known ones)."""
        return self._of(label, where, "tool", self.tool_labels, self.tool_frames)

    @staticmethod
    def _of(label, where, kind, labels, frames) -> np.ndarray:
        if label not in labels:
            raise ValueError(f"{where}: {kind} {label!r} is not in the model (its {kind}s: {', '.join(labels)}); "
                             f"register a series measured {'from' if kind == 'station' else 'with'} it (hykin register) first")
        return frames[labels.index(label)]

    def to_dict(self) -> dict:
        return {"station_labels": list(self.station_labels), "station_bases": self.station_bases.tolist(),
                "tool_labels": list(self.tool_labels), "tool_frames": self.tool_frames.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> StationFrames:
        return cls(tuple(str(x) for x in d["station_labels"]), np.asarray(d["station_bases"], dtype=np.float64).reshape(-1, 4, 4),
                   tuple(str(x) for x in d["tool_labels"]), np.asarray(d["tool_frames"], dtype=np.float64).reshape(-1, 4, 4))


def row_transforms(frames: StationFrames, groups: RowGroups, rows=slice(None)):
    """Per-row ``(L, Rt)``: ``L = B_s · B_0⁻¹`` (reference frame -> the row's station frame) and
    ``Rt = E_0⁻¹ · E_t`` (reference tool -> the row's tool), each ``(N, 4, 4)`` or None when every
    row is in the reference, so that ``T_row = L · T_reference · Rt``."""
    st, tl = groups.station[rows], groups.tool[rows]
    L = Rt = None
    if len(frames.station_labels) > 1:
        Ls = frames.station_bases @ se3.invert(frames.station_bases[0])
        L = Ls[st]
    if len(frames.tool_labels) > 1:
        Rts = se3.invert(frames.tool_frames[0]) @ frames.tool_frames
        Rt = Rts[tl]
    return L, Rt


def apply_row_transforms(T: np.ndarray, L, Rt) -> np.ndarray:
    """``L · T · Rt`` for batches ``(N, 4, 4)`` (None: identity)."""
    if Rt is not None:
        T = T @ Rt
    if L is not None:
        T = L @ T
    return T


def frame_starts(robot, flange: np.ndarray, xyz: np.ndarray, R_meas, groups: RowGroups) -> StationFrames:
    """Closed-form start of every station and tool frame for ``robot`` (its base and tool = the
    reference's). ``flange``: ``(N, 4, 4)`` flange poses in the robot base frame (nominal model, no
    base, no tool); ``xyz`` ``(N, 3)`` or ``(N, K, 3)`` measured points; ``R_meas`` ``(N, 3, 3)`` or None.

    Stations: Kabsch fit of the modelled TCP points (with each row's tool as known so far) onto the
    measured ones (6-D rows: chordal mean of ``T_meas T_model⁻¹``). Tools: least-squares offset of
    ``p = B_s f + B_s F t`` (6-D: chordal mean rotation). Two rounds, so stations measured only with
    other tools and tools seen only from other stations both get a start."""
    pts = xyz if xyz.ndim == 2 else xyz[:, 0]
    S, Tn = len(groups.station_labels), len(groups.tool_labels)
    B = np.tile(np.asarray(robot.base, dtype=np.float64), (S, 1, 1))
    E = np.tile(np.asarray(robot.tool, dtype=np.float64), (Tn, 1, 1))
    known_s = np.zeros(S, bool)
    known_s[0] = True
    known_t = np.zeros(Tn, bool)
    known_t[0] = True
    for _ in range(2):
        for s in range(1, S):
            m = groups.rows_of("station", s) & known_t[groups.tool]
            if m.sum() < (3 if R_meas is None else 1):
                continue
            T_robot = flange[m] @ E[groups.tool[m]]  # TCP in the robot base frame
            if R_meas is None:
                try:
                    Rb, tb = kabsch(T_robot[:, :3, 3], pts[m])
                except ValueError:
                    continue
            else:
                Rb = nearest_rotation(np.einsum("nij,nkj->ik", R_meas[m], T_robot[:, :3, :3]))
                tb = np.mean(pts[m] - T_robot[:, :3, 3] @ Rb.T, axis=0)
            B[s] = se3.make_transform(Rb, tb)
            known_s[s] = True
        for t in range(1, Tn):
            m = groups.rows_of("tool", t) & known_s[groups.station]
            if m.sum() < 2:
                continue
            W = B[groups.station[m]] @ flange[m]  # flange in each row's station frame
            A = W[:, :3, :3].reshape(-1, 3)
            off = np.linalg.lstsq(A, (pts[m] - W[:, :3, 3]).reshape(-1), rcond=None)[0]
            E[t, :3, 3] = off
            if R_meas is not None:
                E[t, :3, :3] = nearest_rotation(np.einsum("nji,njk->ik", W[:, :3, :3], R_meas[m]))
            known_t[t] = True
    return StationFrames(groups.station_labels, B, groups.tool_labels, E)


def to_reference(ds: Dataset, frames: StationFrames, flange_rot: np.ndarray | None = None, *,
                 line_offset: int | None = 1) -> Dataset:
    """``ds`` expressed in the reference station's frame with the reference tool, without its
    ``station``/``tool`` columns (its other columns kept). Each row: ``T' = B_0 B_s⁻¹ T E_t⁻¹ E_0``;
    for position-only rows of another tool the tool change uses the modelled flange rotation
    ``flange_rot`` ``(N, 3, 3)`` (reference frame; needed then). A label the model does not have is a
    :class:`DatasetError` naming the row and the column."""
    n = len(ds)
    where = ds.source or "<dataset>"
    idx = {}
    for col, labels in ((STATION_COLUMN, frames.station_labels), (TOOL_COLUMN, frames.tool_labels)):
        lab = row_labels(ds, col, line_offset=line_offset)
        if lab is None:
            if len(labels) > 1:
                raise DatasetError(f"{where}: no '{col}' column, but the model has several {col}s ({', '.join(labels)}); "
                                   f"add the column naming each row's {col}", file=where, column=col)
            idx[col] = np.zeros(n, np.int64)
            continue
        known = np.isin(lab, np.array(labels, dtype=str))
        if not known.all():
            r = int(np.argmin(known))
            raise row_error(where, f"{col} {str(lab[r])!r} is not in the model (its {col}s: {', '.join(labels)}); "
                            f"register a series measured with it (hykin register) first", r, col, line_offset)
        arr = np.array(labels, dtype=str)
        order = np.argsort(arr)
        idx[col] = order[np.searchsorted(arr[order], lab)].astype(np.int64)
    groups = RowGroups(frames.station_labels, idx[STATION_COLUMN], frames.tool_labels, idx[TOOL_COLUMN], where)
    Ls = frames.station_bases[0] @ se3.invert(frames.station_bases)  # station s frame -> reference frame
    T = ds.poses()
    T = Ls[groups.station] @ T
    xyz = T[:, :3, 3].copy()
    quat = None
    if ds.has_orientation:
        Rts = se3.invert(frames.tool_frames) @ frames.tool_frames[0]  # tool t -> reference tool
        T = T @ Rts[groups.tool]
        xyz, quat = se3.transform_to_pose(T)
    elif len(frames.tool_labels) > 1 and np.any(groups.tool):
        if flange_rot is None:
            raise ValueError("to_reference: position-only rows of several tools need the modelled flange rotations")
        d = frames.tool_frames[0, :3, 3] - frames.tool_frames[groups.tool, :3, 3]  # flange frame, m
        xyz = xyz + np.einsum("nij,nj->ni", flange_rot, d)
    extra = {k: v for k, v in ds.extra.items() if k not in (STATION_COLUMN, TOOL_COLUMN)}
    from ..io.reflectors import reflector_columns

    for names in reflector_columns(ds):  # further reflectors: into the reference station's frame too
        p = np.stack([np.asarray(extra[c], dtype=np.float64) for c in names], 1)
        p = np.einsum("nij,nj->ni", Ls[groups.station, :3, :3], p) + Ls[groups.station, :3, 3]
        extra.update({c: p[:, i] for i, c in enumerate(names)})
    meta = dict(ds.meta, frame=f"station {frames.reference_station!r} (reference), tool {frames.tool_labels[0]!r}")
    return Dataset(q=ds.q, xyz_m=xyz, quat_wxyz=quat, extra=extra, source=ds.source, meta=meta)


def series_labels(ds: Dataset) -> tuple[str | None, str | None]:
    """The one station label and the one tool label of a series to register (None where it has no
    such column). Several labels in a column are a :class:`DatasetError`: a registration fits one
    station frame and one tool frame (register each station's / tool's rows as its own series)."""
    out = []
    where = ds.source or "<dataset>"
    for col in (STATION_COLUMN, TOOL_COLUMN):
        v = row_labels(ds, col)
        u = [] if v is None else sorted(set(v.tolist()))
        if len(u) > 1:
            raise DatasetError(f"{where}: the series has {len(u)} {col}s ({', '.join(u[:6])}); a registration fits one "
                               f"{col} frame: register each {col}'s rows as its own series", file=where, column=col)
        out.append(u[0] if u else None)
    return out[0], out[1]


def add_frames(frames: StationFrames | None, labels: tuple[str | None, str | None], pre: np.ndarray, post: np.ndarray,
               robot) -> tuple[StationFrames | None, np.ndarray, np.ndarray]:
    """Record a registration ``T_meas ≈ pre · T_model · post`` of a series from station / with tool
    ``labels`` (:func:`series_labels`; ``T_model`` in the reference frame of ``robot``, reference tool):
    the station's frame ``B = pre · B_0`` and the tool's ``E = E_0 · post`` are added (or replaced), and
    what they took over leaves the registration frames. Returns ``(frames, pre, post)``. A model fitted
    from one station and tool gets frames whose reference is named ``"training"``."""
    station, tool = labels
    if station is None and tool is None:
        return frames, pre, post
    if frames is None:
        frames = StationFrames(("training",), np.asarray(robot.base, dtype=np.float64)[None].copy(), ("training",),
                               np.asarray(robot.tool, dtype=np.float64)[None].copy())
    out = frames.synced(robot)
    for lab, attr_l, attr_f, F in ((station, "station_labels", "station_bases", None if station is None else pre @ out.station_bases[0]),
                                   (tool, "tool_labels", "tool_frames", None if tool is None else out.tool_frames[0] @ post)):
        if lab is None:
            continue
        labels_now = getattr(out, attr_l)
        if lab in labels_now:
            getattr(out, attr_f)[labels_now.index(lab)] = F
        else:
            setattr(out, attr_l, (*labels_now, lab))
            setattr(out, attr_f, np.concatenate([getattr(out, attr_f), F[None]]))
    return out, (np.eye(4) if station is not None else pre), (np.eye(4) if tool is not None else post)


def station_rms(rp: np.ndarray, groups: RowGroups) -> str:
    """``"A 0.02 mm, B 3.1 mm"``: RMS per station of the position residual ``rp`` ``(N·K, 3)`` m
    (sample-major, every reflector: :func:`hykin.calibration.jacobian.residual`)."""
    n = groups.station.shape[0]
    e2 = np.sum(rp.reshape(n, -1) ** 2, 1) / (rp.size // n // 3)
    rms = np.sqrt(np.bincount(groups.station, e2) / np.bincount(groups.station)) * 1e3
    return ", ".join(f"{lab} {v:.3g} mm" for lab, v in zip(groups.station_labels, rms))


def reference_rows(groups: RowGroups) -> np.ndarray:
    """Rows of the reference station (with the reference tool where it has 12 or more of those): the
    closed-form start of the robot's own base and tool (:func:`hykin.calibration.calibrate.calibrate`)."""
    st = groups.rows_of("station", 0)
    both = st & groups.rows_of("tool", 0)
    return np.flatnonzero(both if both.sum() >= 12 else st)
