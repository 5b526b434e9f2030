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
import sys
import types

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
    "ik_numeric": "ik",
    "IKResult": "ik",
    "IKBranches": "ik",
    "ik_closed_form": "ik_analytic",
    "has_closed_form": "ik_analytic",
    # data
    "Dataset": "dataset",
    "DatasetError": "dataset",
    "read_dataset": "dataset",
    "write_dataset": "dataset",
    "split": "dataset",
    "validate": "dataset",
    "read_joints": "dataset",
    "read_poses": "dataset",
    "dataset_hash": "dataset",
    "import_ur5": "importers",
    "import_ipa_series": "importers",
    "import_three_smr": "importers",
    "import_table": "table_import",
    "TableMap": "table_map",
    "load_table_map": "table_map",
    "suggest_map": "table_map",
    # physics, simulation
    "gravity_torques": "compliance",
    "deflected_joints": "compliance",
    "compliant_fk": "compliance",
    "VirtualRobot": "simulate",
    "simulate": "simulate",
    "virtual_preset": "simulate",
    "list_virtual_presets": "simulate",
    "sample": "sampling",
    "iso_cube": "sampling",
    "save_truth": "simulate",
    "load_truth": "simulate",
    "simulate_to_file": "simulate",
    # calibration, hybrid model
    "calibrate": "calibrate",
    "CalibrationResult": "calibrate",
    "calibrated_fk": "calibrate",
    "apply_deviations": "calibrate",
    "CalibrationError": "calibrate",
    "initial_registration": "initial_registration",
    "InitialRegistration": "initial_registration",
    "reflector_points": "reflectors",
    "DEFAULT_MAX_DEVIATION": "calibration_checks",
    "HybridModel": "hybrid",
    "OutOfRangeWarning": "hybrid",
    "ModelFileError": "modelfile",
    "UnverifiedModelWarning": "modelfile",
    "PlausibilityError": "plausibility",
    "check_dataset": "plausibility",
    "make_net": "nets",
    "list_architectures": "nets",
    "get_recipe": "train",
    "hybrid_ik": "hybrid_ik",
    "wang_ik": "hybrid_ik",
    "HybridIKResult": "hybrid_ik",
    "ik_result_to_rows": "hybrid_ik",
    "branch_count_report": "hybrid_ik",
    "BranchCountReport": "hybrid_ik",
    "ThermalFit": "thermal",
    "extrapolation_growth": "uncertainty",
    "register_model": "register",
    "RegistrationError": "register",
    "calibrate_fade": "fade",
    "select_calibration": "region_cv",
    "export_onnx": "export",
    "calibrated_urdf": "urdf",
    "compensate": "compensation",
    "Compensation": "compensation",
    "evaluate_model": "evaluate",
    "evaluate_per_payload": "evaluate",
    # payload per row
    "PAYLOAD_COLUMNS": "payload",
    "payload_of": "payload",
    "with_payload": "payload",
    "robot_with_payload": "payload",
    "model_with_payload": "payload",
    "errors_per_payload": "payload",
    "Report": "report",
    # evaluation, measurement
    "error_stats": "metrics",
    "pose_errors": "metrics",
    "format_table": "metrics",
    "kabsch": "referencing",
    "fit_plane": "referencing",
    "fit_circle_3d": "referencing",
    "axis_from_sweep": "referencing",
    "base_frame_from_sweeps": "referencing",
    "tool_frame_from_sweeps": "referencing",
    "pose_from_three_points": "referencing",
    "estimate_time_offset": "streams",
    "align_streams": "streams",
    "iso9283_pose": "iso9283",
    # measurement planning
    "plan_poses": "planning",
    "active_poses": "planning",
    "Plan": "planning",
    "PlanningError": "planning",
    "forecast_accuracy": "planning",
}

__all__ = sorted(_EXPORTS) + ["__version__"]

# Functions named like their modules (hykin.fk, hykin.ik, hykin.simulate, hykin.calibrate,
# hykin.hybrid_ik): the public name is the function. Python's import system sets the package
# attribute to the submodule when the submodule is first imported; this package type ignores that
# assignment, so `hykin.fk` stays the function. Submodules remain importable by their full name
# (`from hykin.fk import jacobian`, `importlib.import_module("hykin.fk")`).
_SHADOWED = frozenset(name for name, mod in _EXPORTS.items() if name == mod)


class _Package(types.ModuleType):
    def __setattr__(self, name, value):
        if name in _SHADOWED and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


def __getattr__(name: str):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'hykin' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{mod}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
