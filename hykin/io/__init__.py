"""Files: datasets, robot files, URDF, model files, and the checks that data fit a robot.

:mod:`.dataset` (the :class:`Dataset` dataclass, validation, split, hash), :mod:`.dataset_files`
(CSV/Parquet reading and writing with declared units), :mod:`.text_table` (the one delimited-text
reader), :mod:`.csv_writer` (the one CSV writer), :mod:`.payload` (per-row payload columns),
:mod:`.reflectors` (extra reflector columns), :mod:`.plausibility` (unit slips, quaternion order,
reach: data against the robot), :mod:`.robot_toml` / :mod:`.robot_file` (TOML robot files, presets),
:mod:`.urdf`, :mod:`.urdf_flange` (the flange link programs give tools from), :mod:`.robot_codec` (the one JSON robot
codec), :mod:`.modelfile` (safetensors model
files with an integrity hash). Depends on :mod:`hykin.kinematics` and :mod:`hykin.geometry`.
"""
