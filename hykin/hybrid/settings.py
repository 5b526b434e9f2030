"""Settings of the hybrid model: their validation (run by ``fit`` and ``load``, not by the
constructor: scikit-learn contract) and the empty fitted state ``fit`` starts from."""

from __future__ import annotations

import numpy as np

from .errors import HybridError
from .nets import make_net
from .support import PAIR_GRID

__all__ = ["check_settings", "empty_fitted_state"]

#: enumerated settings: name -> (allowed values, how the message names them)
CHOICES = {
    "normalise": (("data", "full"), "'data' or 'full'"),
    "fade": ((True, False, "support", "range", "full"), "True, False, 'support', 'range' or 'full'"),
    "periodic": (("wrap", "none"), "'wrap' or 'none'"),
    "joint1": (("input", "frame"), "'input' or 'frame'"),
    "thermal": ((True, False, "auto"), "True, False or 'auto'"),
    "payload_input": ((True, False, "auto"), "True, False or 'auto'"),
    "uncertainty": ((True, False), "True or False"),
}


def check_settings(model) -> tuple[int, ...]:
    """Validate the settings of a hybrid ``model`` (:class:`HybridError` naming the bad one;
    ValueError for an unknown architecture or recipe). Returns the 1-based input joints."""
    for name, (allowed, words) in CHOICES.items():
        v = getattr(model, name)
        if v not in allowed:
            raise HybridError(f"{name} must be {words}, got {v!r}")
    if not (model.fade_width > 0):
        raise HybridError(f"fade_width must be > 0, got {model.fade_width}")
    n = model.robot.dof
    try:
        ij = model.resolved_input_joints()
    except (TypeError, ValueError):
        ij = ()
    if not ij or any(not 1 <= j <= n for j in ij) or len(set(ij)) != len(ij):
        raise HybridError(f"input_joints must be distinct joint numbers in 1..{n}, got {model.input_joints!r}")
    model.resolved_recipe()  # ValueError naming an unknown recipe or field
    make_net(model.arch, 1)  # ValueError naming an unknown architecture
    return ij


def empty_fitted_state(n: int) -> dict:
    """The fitted attributes of a hybrid model for ``n`` joints before ``fit`` sets them."""
    return {
        "robot_": None, "net_pos_": None, "net_rot_": None, "meta_": {},
        "calibration_": None,  # CalibrationResult of the last fit (not saved; its summary is in meta_)
        "calibration_cv_": None,  # RegionCVResult when calibrate_kw selects by region CV
        "fade_calibration_": None,  # FadeCalibration when fade_cv >= 2
        "wrap_centre_": np.full(n, np.nan),  # per joint, NaN = not wrapped
        "j1_axis_": None,  # unit joint-1 axis (world frame) when joint1 == "frame"
        "unc_": None,  # validation error quantiles (predict_uncertainty; hykin.hybrid.bands)
        "thermal_": None,  # ThermalFit when the training data had a temperature column
        "pair_index_": np.zeros((0, 2), dtype=np.int64),  # joint pairs of the hole grids
        "pair_gap_": np.zeros((0, PAIR_GRID, PAIR_GRID)),  # (P, G, G) gap at the grid nodes
        "payload_range_": None,  # PayloadRange of the training data (payload_kg column)
        "payload_input_": False,  # payload is a network input (training data with several payloads)
        "payload_default_kg_": None,  # payload the networks see when predict gets none (None: robot_'s)
        "frame_pre_": np.eye(4),  # registration frames: T = frame_pre_ · T_model(q) · frame_post_
        "frame_post_": np.eye(4),
        "station_frames_": None,  # StationFrames of several stations / tools (hykin.hybrid.stations)
    }
