"""Kinematics of a serial robot: the robot model and its forward and inverse kinematics.

:mod:`.robot` (the :class:`Robot` dataclass of arrays: DH/MDH/URDF joints, limits, masses, stiffness,
base, tool), :mod:`.chain` (the joint chain of any convention as fixed transforms + joint axes),
:mod:`.walk` (the one chain walk: array-API for numpy/torch, numba per-joint step), :mod:`.fk`
(batched FK, frames, Jacobian, torch FK), :mod:`.compliance` (gravity torques and joint deflection),
:mod:`.classical` (the classical prediction: FK with compliance), :mod:`.lm` (the one batched projected
Levenberg-Marquardt), :mod:`.ik` (numerical and closed-form IK, all branches), ``ik_*`` modules (closed
form: :mod:`.poe`, :mod:`.ik_subproblems`, :mod:`.ik_families`, :mod:`.ik_closed_form`; shared results
:mod:`.ik_solutions`; failure reasons :mod:`.ik_reasons`; output rows :mod:`.ik_rows`). Depends on
:mod:`hykin.geometry`.
"""
