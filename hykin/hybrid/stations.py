"""Several stations and tools in a hybrid model (:mod:`hykin.calibration.stations` for the method).

The calibration fits every station's and tool's frame jointly with the robot; the model keeps them
(``station_frames_``, saved in the model file) and its networks learn from the training data
expressed in ONE frame: the reference station's (the calibrated robot's ``base``), with the
reference tool. :func:`in_model_frame` does that for training, validation and test data;
:func:`station_transform` maps the model's poses into a named station's frame and onto a named tool
(``hykin fk --station / --tool``).
"""

from __future__ import annotations

import numpy as np

from ..calibration.stations import StationFrames, row_groups, to_reference
from ..geometry import se3
from ..kinematics.classical import classical_fk

__all__ = ["fit_station_frames", "in_model_frame", "station_transform"]


def fit_station_frames(model, train) -> StationFrames | None:
    """The station / tool frames of ``model`` after its calibration on ``train`` (None: one frame).
    Without a calibration (``calibrate=False``) only the further stations' and tools' frames are fitted
    (the robot file's own base and tool stay the reference's)."""
    if getattr(model, "calibration_", None) is not None:
        return model.calibration_.station_frames
    groups = row_groups(train, len(train))
    if groups is None:
        return None
    from ..calibration.calibrate import calibrate

    pats = [f"station[[]{lab}].*" for lab in groups.station_labels[1:]] + [f"tool[[]{lab}].*" for lab in groups.tool_labels[1:]]
    res = calibrate(model.robot, train, params=pats, compliance=False, initial=False, checks=False)
    return res.station_frames


def in_model_frame(model, ds, *, line_offset: int | None = 1):
    """``ds`` in the frame the model's networks learn in (the reference station, reference tool),
    without its ``station``/``tool`` columns; ``ds`` itself when the model has one frame. A row of a
    station or tool the model does not know is a :class:`hykin.io.dataset.DatasetError` (row, column)."""
    fr = getattr(model, "station_frames_", None)
    if ds is None:
        return ds
    if fr is None:
        _check_one_frame(ds)
        return ds
    flange = None
    if not ds.has_orientation and len(fr.tool_labels) > 1:
        flange = classical_fk(model.robot_.copy(tool=np.eye(4)), ds.q)[:, :3, :3]
    return to_reference(ds, fr, flange, line_offset=line_offset)


def _check_one_frame(ds) -> None:
    """Refuse (:class:`hykin.io.dataset.DatasetError`) data with several stations or tools for a model
    fitted in one frame: it would compare every row in that frame (metres off, without a word)."""
    groups = row_groups(ds, len(ds))
    if groups is None:
        return
    for col, labels in (("station", groups.station_labels), ("tool", groups.tool_labels)):
        if len(labels) > 1:
            from ..io.dataset import DatasetError

            shown = ", ".join(repr(str(x)) for x in labels[:4]) + (", ..." if len(labels) > 4 else "")
            raise DatasetError(
                f"{ds.source or '<dataset>'}: column '{col}' names {len(labels)} {col}s ({shown}) but the model was "
                f"fitted with one {col} (no '{col}' column): its poses are in one frame; register the model to each "
                f"{col}'s rows, one series at a time (hykin register; docs/stations.md), or fit with the column",
                file=ds.source, column=col)


def station_transform(model, station: str | None, tool: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(L, Rt)`` ``(4, 4)`` each, so that ``L · T · Rt`` is a pose ``T`` of the model (the reference
    station's frame and tool, where :meth:`predict` works) in station ``station``'s frame with tool
    ``tool``: ``L = B_s · B_0⁻¹``, ``Rt = E_0⁻¹ · E_t`` (identity for None). ValueError naming the
    model's stations / tools for an unknown one."""
    if station is None and tool is None:
        return np.eye(4), np.eye(4)
    fr = getattr(model, "station_frames_", None)
    if fr is None:
        opt = "--station" if station is not None else "--tool"
        raise ValueError(f"{opt} {station if station is not None else tool!r}: this model was fitted with one station and "
                         "one tool (no station / tool column); its poses are in the frame of its robot base")
    L = np.eye(4) if station is None else fr.base_of(str(station), "--station") @ se3.invert(fr.station_bases[0])
    Rt = np.eye(4) if tool is None else se3.invert(fr.tool_frames[0]) @ fr.tool_of(str(tool), "--tool")
    return L, Rt
