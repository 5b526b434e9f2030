"""Where a program's own tool sits on the real robot: the reading of the calibrated TCP's shift.

Data measured at one TCP (a reflector on a mount) identify the chain up to the last joint and one fixed
transform after it, the model's TCP. The flange's own errors (the last link's, after the last joint's
rotation) and the measurement tool's mount are one transform there: no data of that TCP tells them
apart, and several tools share the flange. The model's TCP is ``E`` from the robot file's
(:func:`hykin.hybrid.ik_result.model_tcp_shift`). A program's tool ``P`` (KRL ``TOOL_DATA``, RAPID
``tooldata``, URScript ``set_tcp``, ``--tool``; given relative to the flange, ``D = inv(F_tool) P``
relative to the file's TCP ``F_tool``) then sits:

* ``"mount"`` (default): ``E`` is the measurement tool's mount (or a rough ``[tool]`` in the robot file):
  ``P`` is fixed to the calibrated chain's flange, TCP ``chain · P`` (``D`` relative to the model's TCP
  is ``inv(E) · D``). A file tool guessed 30 mm off then moves no program target.
* ``"flange"``: ``E`` is the flange's own error (the file's ``[tool]`` is the measurement tool as measured,
  e.g. a reflector nest's calibrated offset): ``P`` moves with it, TCP ``chain · F_tool · E · D``.

The two readings put ``P``'s TCP :func:`ambiguity` apart (``pose_error(D, E · D)``): probe s42 AU's
0.84 mm shift was 0.77 mm at a 180 mm tool, every target "ok". :func:`tool_shift_note` says so whenever
that exceeds the model's accuracy.
"""

from __future__ import annotations

import numpy as np

from ..geometry import se3

__all__ = ["TOOL_SHIFTS", "ambiguity", "model_delta", "tcp_shift_inv", "tool_shift_note"]

TOOL_SHIFTS = ("mount", "flange")


def tcp_shift_inv(model) -> np.ndarray:
    """``inv(E)``, ``E`` the model's TCP relative to the robot file's (:func:`hykin.hybrid.ik_result.model_tcp_shift`)."""
    from ..hybrid.ik_result import model_tcp_shift

    return se3.invert(model_tcp_shift(model))


def check_tool_shift(reading: str) -> str:
    """``reading`` if it is one of :data:`TOOL_SHIFTS`, else ValueError naming them."""
    if reading not in TOOL_SHIFTS:
        raise ValueError(f"tool_shift must be one of {', '.join(TOOL_SHIFTS)}, got {reading!r}")
    return reading


def model_delta(model, D: np.ndarray | None, given=None, shift_inv=None, reading: str = "mount") -> np.ndarray | None:
    """The program TCP relative to the *model's* TCP, from ``D`` ``(N, 4, 4)`` relative to the robot file's
    TCP (the controller's view, used for the command), under ``reading`` (module docstring): ``inv(E) · D``
    ("mount"; ``shift_inv``: ``inv(E)`` when known) or ``D`` ("flange"). ``given`` ``(N,)`` bool: the rows
    with a program tool (default all); the others (identity ``D``: the robot file's TCP, which the model's
    TCP stands for) stay as they are."""
    if D is None:
        return None
    if check_tool_shift(reading) == "flange":
        return D
    Dm = (tcp_shift_inv(model) if shift_inv is None else shift_inv) @ D
    return Dm if given is None else np.where(np.asarray(given, dtype=bool)[:, None, None], Dm, D)


def ambiguity(model, D: np.ndarray, E: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(mm (N,), deg (N,))``: how far the two readings put the TCPs ``D`` ``(N, 4, 4)`` (relative to the
    robot file's TCP) apart. ``E``: the model's TCP relative to the file's, where the caller has it."""
    from ..hybrid.ik_result import model_tcp_shift

    D = np.asarray(D, dtype=np.float64)
    pe, ae = se3.pose_error(D, (model_tcp_shift(model) if E is None else E) @ D)
    return np.asarray(pe, dtype=np.float64), np.asarray(ae, dtype=np.float64)


def tool_shift_note(model, D: np.ndarray | None, given, reading: str, accuracy_mm: float) -> list:
    """``[note]`` where the targets with a program tool (``given`` ``(N,)`` bool, None: all rows of ``D``)
    land farther apart under the two readings than ``accuracy_mm`` (the model's), or turned by more than the
    model's orientation accuracy (probe s42 AV: a mostly rotational shift went unsaid); else ``[]``."""
    from ..hybrid.ik_result import model_accuracy, model_tcp_shift

    if D is None:
        return []
    rows = np.ones(len(D), dtype=bool) if given is None else np.asarray(given, dtype=bool)
    if not rows.any():
        return []
    E = model_tcp_shift(model)
    pe, ae = ambiguity(model, np.asarray(D)[rows], E)
    acc_deg = model_accuracy(model)[1] or 1e-4
    if not (pe.max() > accuracy_mm or ae.max() > acc_deg):
        return []
    e_mm, e_deg = float(np.linalg.norm(E[:3, 3]) * 1e3), float(np.degrees(np.linalg.norm(se3.matrix_to_rotvec(E[:3, :3]))))
    other = "flange" if reading == "mount" else "mount"
    told = {"mount": "the measurement tool's mount (its program tools are fixed to the calibrated chain's flange)",
            "flange": "the flange's own error (the program tools move with it)"}
    return [f"the calibrated TCP is {e_mm:.3g} mm / {e_deg:.3g}° from the robot file's [tool]: the data cannot tell "
            f"the flange's own error from the measurement tool's mount (both lie after the last joint). Taken as "
            f"{told[reading]} (--tool-shift {reading}); with --tool-shift {other} the {int(rows.sum())} targets with "
            f"a program tool would land up to {pe.max():.3g} mm / {ae.max():.3g}° elsewhere, more than the model's "
            f"accuracy ({accuracy_mm:.3g} mm / {acc_deg:.3g}°). 'flange' is right where the robot file's [tool] is the measurement "
            "tool as measured (a reflector nest's calibrated offset); to remove the doubt, measure with the "
            "program's tool"]
