"""Compensated targets (DESIGN.md §6): what to ask a controller running its nominal model for.

For each wanted TCP pose: hybrid IK on the branch the caller means (joints near ``q_branch``) gives
the joints ``q`` at which the *real* robot (as the model knows it) reaches the pose; the nominal
model's FK of ``q`` — in the nominal robot's base frame, with the nominal tool — is the command. A
controller that runs the nominal model and solves its own IK on that branch then lands at ``q``.

Frames (``frame``):

* ``"measurement"``: targets are in the model's measurement frame (the frame of its training data).
  For a model fitted on robot-frame data this is the controller's base frame, and errors of the
  robot's base are compensated too.
* ``"base"``: targets are in the controller's base frame, placed in the measurement frame by the
  model's *fitted* base (``frame_pre · robot_.base``): the choice for models fitted on tracker-frame
  data, where the measurement frame is arbitrary. The base's own error cannot be compensated then
  (it defines the frame); the arm's, the tool's and the networks' errors are.
* ``"auto"`` (:func:`resolve_frame`): ``"base"`` when the fitted base is over 50 mm or 5° from the
  nominal base (tracker-frame data), else ``"measurement"``.

Commands are always ``inv(nominal.base) · FK_nominal(q) · tool_delta`` (controller base frame).
``tool_delta`` (``(4, 4)`` or ``(N, 4, 4)``) is the program's TCP relative to the nominal tool
(URScript ``set_tcp``): the wanted pose is then of that TCP. That TCP is fixed to the real flange, whose
TCP is the model's (the calibrated tool, with a registration's ``frame_post``), so the model's TCP target
is ``T · inv(tool_delta) · E`` with ``E`` the model's TCP relative to the nominal one
(:func:`hykin.compensation.tool_shift.model_delta`; a robot file whose ``[tool]`` is a guess no longer
carries the guess's error into the program's TCP). The split between the last link and the tool is the
calibration's: a tool offset along the last joint's axis that the data cannot tell from that joint's
``d`` / ``theta`` stays in the tool.

An unreachable target (no hybrid solution within the joint limits, or no nominal solution on the
meant branch) gets ``success = False``, a reason and NaN command/joints — never a made-up command.
"""

from __future__ import annotations

from .compensator import Compensator, StepResult, compensate
from .frames import FRAMES, fitted_base, parse_targets, resolve_frame, to_model_frame
from .result import Compensation, command_rows, first_row_per_target

__all__ = ["FRAMES", "Compensation", "Compensator", "StepResult", "command_rows", "compensate", "first_row_per_target",
           "fitted_base", "parse_targets", "resolve_frame", "to_model_frame"]
