"""Getting accuracy into a controller that runs its nominal model (DESIGN.md §6).

* :mod:`.compensator` — :class:`Compensator` (loads a model once; one target or a batch) and
  :func:`compensate`: hybrid IK on the meant branch → nominal FK = the command.
* :mod:`.targets` — frames and commands of compensation (docs); :mod:`.frames`, :mod:`.result` hold them.
* :mod:`.branches` — KUKA ``S``/``T`` status, ABB ``confdata``, and the nominal solution they mean.
* :mod:`.programs` — shared rewriting machinery: targets found in a program text, replaced in place.
* :mod:`.program_branches` — which solution each program target means (configuration data, the walk).
* :mod:`.program_checks` — what the controller will do with the written targets' configuration data:
  changes refused or noted.
* :mod:`.walk_checks` — targets without configuration data (a program's walk, a list of targets) as the
  controller executes them from the joints it stands at; :mod:`.redundant_walk` for arms of 7+ joints.
* :mod:`.local_controller` — targets with the joints the robot stands at (a step, given joints) as a
  local-IK controller executes them.
* :mod:`.tool_shift` — where a program's own tool sits: the two readings of the calibrated TCP's shift.
* :mod:`.target_checks` — targets read from a file checked before compensation (quaternion order).
* :mod:`.urscript`, :mod:`.krl`, :mod:`.rapid` — the three program formats.
* :mod:`.service` — the FastAPI app of ``hykin serve``: HTTP batches and a WebSocket stream (imports FastAPI only when used).
* :mod:`.service_requests` — its requests: checks, the model calls, replies.
* :mod:`.service_guard` — its limits: bearer token, body size, the one bounded model queue, /health identity.
* :mod:`.service_protocol` — its connections before a request: header deadline, cap on waiting connections.
"""

from __future__ import annotations

from .compensator import Compensator, StepResult, compensate
from .frames import resolve_frame
from .result import Compensation

__all__ = ["Compensation", "Compensator", "StepResult", "compensate", "resolve_frame"]
