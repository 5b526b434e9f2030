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
    "Robot": "kinematics.robot",
    "RobotFileError": "kinematics.robot",
    "load_robot": "io.robot_file",
    "load_robot_toml": "io.robot_toml",
    "save_robot_toml": "io.robot_toml",
    "list_presets": "io.robot_file",
    "dh_to_mdh": "kinematics.robot",
    "mdh_to_dh": "kinematics.robot",
    "load_urdf": "io.urdf",
    "robot_to_urdf": "io.urdf",
    "build_chain": "kinematics.chain",
    "fk": "kinematics.fk",
    "fk_frames": "kinematics.fk",
    "fk_torch": "kinematics.fk",
    "jacobian": "kinematics.fk",
    "ik": "kinematics.ik",
    "ik_numeric": "kinematics.ik",
    "IKResult": "kinematics.ik_solutions",
    "IKBranches": "kinematics.ik_solutions",
    "ik_closed_form": "kinematics.ik",
    "has_closed_form": "kinematics.ik_closed_form",
    # data
    "Dataset": "io.dataset",
    "DatasetError": "io.dataset",
    "read_dataset": "io.dataset_files",
    "write_dataset": "io.dataset_files",
    "split": "io.dataset",
    "validate": "io.dataset",
    "read_joints": "io.dataset_files",
    "read_poses": "io.dataset_files",
    "dataset_hash": "io.dataset",
    "import_ur5": "measure.importers",
    "import_ipa_series": "measure.importers",
    "import_three_smr": "measure.importers",
    "import_table": "measure.table_import",
    "TableMap": "measure.table_map",
    "load_table_map": "measure.table_map",
    "suggest_map": "measure.table_map",
    # physics, simulation
    "gravity_torques": "kinematics.compliance",
    "deflected_joints": "kinematics.compliance",
    "compliant_fk": "kinematics.compliance",
    "VirtualRobot": "sim.simulate",
    "simulate": "sim.simulate",
    "virtual_preset": "sim.presets",
    "list_virtual_presets": "sim.presets",
    "sample": "sim.sampling",
    "iso_cube": "sim.sampling",
    "save_truth": "sim.simulate",
    "load_truth": "sim.simulate",
    "simulate_to_file": "sim.generate",
    # calibration, hybrid model
    "calibrate": "calibration.calibrate",
    "CalibrationResult": "calibration.calibrate",
    "calibrated_fk": "calibration.calibrate",
    "apply_deviations": "calibration.calibrate",
    "CalibrationError": "calibration.calibrate",
    "initial_registration": "calibration.initial_registration",
    "InitialRegistration": "calibration.initial_registration",
    "reflector_points": "io.reflectors",
    "DEFAULT_MAX_DEVIATION": "calibration.checks",
    "StationFrames": "calibration.stations",
    "to_reference": "calibration.stations",
    "DEFAULT_PRIORS": "calibration.priors",
    "HybridModel": "hybrid.model",
    "OutOfRangeWarning": "hybrid.errors",
    "ModelFileError": "io.modelfile",
    "UnverifiedModelWarning": "io.modelfile",
    "PlausibilityError": "io.plausibility",
    "check_dataset": "io.plausibility",
    "make_net": "hybrid.nets",
    "list_architectures": "hybrid.nets",
    "get_recipe": "hybrid.train",
    "hybrid_ik": "hybrid.ik",
    "wang_ik": "hybrid.ik",
    "HybridIKResult": "hybrid.ik_result",
    "ik_result_to_rows": "hybrid.ik_report",
    "branch_count_report": "hybrid.ik_report",
    "BranchCountReport": "hybrid.ik_report",
    "ThermalFit": "calibration.thermal",
    "extrapolation_growth": "hybrid.uncertainty",
    "register_model": "measure.register",
    "RegistrationError": "measure.register",
    "RobotModel": "measure.robot_model",
    "OptionalStepWarning": "hybrid.optional",
    "calibrate_fade": "hybrid.fade",
    "select_calibration": "hybrid.region_cv",
    "export_onnx": "hybrid.export",
    "calibrated_urdf": "io.urdf",
    "compensate": "compensation",
    "Compensation": "compensation",
    "Compensator": "compensation",
    "evaluate_model": "evaluation.evaluate",
    "evaluate_per_payload": "evaluation.evaluate",
    # payload per row
    "PAYLOAD_COLUMNS": "io.payload",
    "payload_of": "io.payload",
    "with_payload": "io.payload",
    "robot_with_payload": "io.payload",
    "model_with_payload": "io.payload",
    "errors_per_payload": "io.payload",
    "Report": "evaluation.report",
    "build_report": "evaluation.report_build",
    "write_report": "evaluation.report_build",
    # evaluation, measurement
    "error_stats": "evaluation.metrics",
    "pose_errors": "evaluation.metrics",
    "format_table": "evaluation.metrics",
    "kabsch": "geometry.rigid",
    "fit_plane": "measure.fits",
    "fit_circle_3d": "measure.fits",
    "axis_from_sweep": "measure.fits",
    "base_frame_from_sweeps": "measure.referencing",
    "tool_frame_from_sweeps": "measure.referencing",
    "pose_from_three_points": "geometry.rigid",
    "estimate_time_offset": "measure.streams",
    "align_streams": "measure.streams",
    "iso9283_pose": "evaluation.iso9283",
    # measurement planning
    "plan_poses": "planning",
    "active_poses": "planning",
    "Plan": "planning",
    "PlanningError": "planning",
    "forecast_accuracy": "planning",
    # sweeps and fleets on Ray (extra `distributed`)
    "read_sweep": "distributed.sweep_file",
    "run_sweep": "distributed.sweep",
    "read_fleet": "distributed.fleet_file",
    "run_fleet": "distributed.fleet",
    "run_trial": "distributed.trials",
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
