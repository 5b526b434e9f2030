"""Geometry under everything: rigid transforms and fits of point sets (float64, m and rad).

:mod:`.se3` (4x4 transforms, rotation vectors, quaternions wxyz, RPY/Euler, pose errors in mm and
degrees, torch twins), :mod:`.rigid` (the one rigid/similarity point-set fit: Umeyama/Kabsch,
registration with uncertainty, pose from three reflectors), :mod:`.lsq` (input checks and least-squares
covariance shared by the fits). Depends on numpy/scipy only.
"""
