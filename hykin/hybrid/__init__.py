"""The hybrid model: calibrated classical model + residual networks (DESIGN.md §1.1, §1.3).

:mod:`.model` (:class:`HybridModel`, scikit-learn contract), :mod:`.settings`, :mod:`.fitting`,
:mod:`.inputs` (what the networks see), :mod:`.support` (training support and fade),
:mod:`.fade` / :mod:`.region_cv` (fade and calibration choice from held-out regions), :mod:`.bands` /
:mod:`.uncertainty` (conformal bands and their growth), :mod:`.thermal_fit`, :mod:`.rotations`,
:mod:`.persistence` (the model file), :mod:`.stations` (station / tool frames of a model), :mod:`.nets` / :mod:`.train` (architectures, recipes),
:mod:`.export` (ONNX), :mod:`.errors`, :mod:`.progress`; hybrid inverse kinematics in :mod:`.ik`
(API) with :mod:`.ik_result`, :mod:`.ik_seeds`, :mod:`.ik_solve`, :mod:`.ik_roots`, :mod:`.ik_report`,
:mod:`.self_motion` (a redundant arm's solution nearest given joints).
Depends on :mod:`hykin.calibration`, :mod:`hykin.io`, :mod:`hykin.kinematics`, :mod:`hykin.geometry`.
"""
