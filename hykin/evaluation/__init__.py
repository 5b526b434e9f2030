"""How good a model is: error statistics, ISO 9283, evaluation tables and reports.

:mod:`.metrics` (mean / std / p95 / max in mm and degrees), :mod:`.iso9283` (AP, RP),
:mod:`.evaluate` (nominal vs calibrated vs hybrid tables, per joint region and per payload),
:mod:`.report_build` (THE report: one builder for ``hykin report``, ``evaluate --report`` and ``demo``)
over :mod:`.report` (the HTML document), :mod:`.report_figures`, :mod:`.report_card` (model card),
:mod:`.report_accuracy` (tables), :mod:`.report_calibration` (calibration table), :mod:`.report_summary`
(the summary in words) and :mod:`.report_ik` (warm IK timing). Depends on :mod:`hykin.hybrid` (the report
 only), :mod:`hykin.calibration`, :mod:`hykin.io`,
:mod:`hykin.kinematics`, :mod:`hykin.geometry`.
"""
