"""How good a model is: error statistics, ISO 9283, evaluation tables and reports.

:mod:`.metrics` (mean / std / p95 / max in mm and degrees), :mod:`.iso9283` (AP, RP),
:mod:`.evaluate` (nominal vs calibrated vs hybrid tables, per joint region and per payload),
:mod:`.report` (HTML/PNG reports). Depends on :mod:`hykin.calibration`, :mod:`hykin.io`,
:mod:`hykin.kinematics`, :mod:`hykin.geometry`.
"""
