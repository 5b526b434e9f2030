"""Parametric calibration of the classical model (DESIGN.md §1.4).

:mod:`.calibrate` (the calibration: start, base/tool, full identification, restart; the public
:func:`calibrate`), :mod:`.params` (parameter specs and model state), :mod:`.jacobian` (measurement
model, residuals, analytic identification Jacobian), :mod:`.result` (:class:`CalibrationResult`),
:mod:`.checks` (refusals: not converged, a parameter beyond its tolerances, implausible residual),
:mod:`.priors` (tolerance per kind of the robot file's values, the excitation test), :mod:`.posterior`
(prior rows of the normal equations, posterior covariance and status), :mod:`.initial_registration`
(closed-form start in any tracker frame), :mod:`.frames` (base/tool frame fit ``T_meas ≈ B·T·E`` and
the choice of registration poses), :mod:`.thermal` (uniform thermal expansion), :mod:`.stations` (several stations / tools in one
dataset: row groups, their frames, data in the reference frame), :mod:`.outliers` (rows far off the
calibrated model: named, left out; joints and measurements out of step), :mod:`.identifiability`
(which parameters a scaled Jacobian can tell apart). Depends on
:mod:`hykin.io`, :mod:`hykin.kinematics`, :mod:`hykin.geometry`.
"""
