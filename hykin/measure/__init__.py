"""Measurements: getting tracker data into hykin and a new series onto a model.

:mod:`.importers` (UR5, IPA UR10, three-reflector nests), :mod:`.table_map` / :mod:`.table_import`
(any table through a mapping: ``hykin import table``), :mod:`.orientation_names` / :mod:`.orientation_fit`
(orientation columns against their names and against the robot's rotations), :mod:`.referencing` (base and tool frames from
joint sweeps), :mod:`.fits` (plane, circle, axis fits with uncertainty), :mod:`.streams` (clock
alignment of robot and tracker streams), :mod:`.stream_checks` (is it a stream, is the clock a result),
:mod:`.stream_files` (the plain stream layout, read in chunks), :mod:`.register` (registration of a new series to a fitted
model: ``hykin register``). Depends on :mod:`hykin.calibration`, :mod:`hykin.io`,
:mod:`hykin.kinematics`, :mod:`hykin.geometry`.
"""
