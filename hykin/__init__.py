"""hykin — high-accuracy hybrid kinematics for serial robot arms.

A classical kinematic model (DH / modified DH / URDF), calibrated from measured poses, plus residual
neural networks for position and orientation; forward and inverse kinematics at measurement accuracy.

The public API is re-exported here lazily, so ``import hykin`` stays fast and does not import torch
until a torch-backed part is used::

    import hykin
    robot = hykin.load_robot("rx160")
    T = hykin.fk(robot, q)                      # (N, 4, 4)
    model = hykin.HybridModel(robot).fit(train)
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it
_EXPORTS = {
    # robots and kinematics
    "Robot": "robot",
    "RobotFileError": "robot",
    "load_robot": "robot",
    "load_robot_toml": "robot",
    "save_robot_toml": "robot",
    "list_presets": "robot",
    "dh_to_mdh": "robot",
    "mdh_to_dh": "robot",
    "load_urdf": "urdf",
    "robot_to_urdf": "urdf",
    "build_chain": "chain",
    "fk": "fk",
    "fk_frames": "fk",
    "fk_torch": "fk",
    "jacobian": "fk",
    "ik": "ik",
    "ik_closed_form": "ik_analytic",
    "has_closed_form": "ik_analytic",
    # data
    "Dataset": "dataset",
    "DatasetError": "dataset",
    "read_dataset": "dataset",
    "write_dataset": "dataset",
    "split": "dataset",
    "validate": "dataset",
    # physics, simulation
    "gravity_torques": "compliance",
    "deflected_joints": "compliance",
    "compliant_fk": "compliance",
    "VirtualRobot": "simulate",
    "simulate": "simulate",
    "virtual_preset": "simulate",
    "list_virtual_presets": "simulate",
    "sample": "sampling",
    # calibration, hybrid model
    "calibrate": "calibrate",
    "CalibrationResult": "calibrate",
    "HybridModel": "hybrid",
    "hybrid_ik": "hybrid_ik",
    "wang_ik": "hybrid_ik",
    # evaluation, measurement
    "error_stats": "metrics",
    "kabsch": "referencing",
    "iso9283_pose": "iso9283",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'hykin' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{mod}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
