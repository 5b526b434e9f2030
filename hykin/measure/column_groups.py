"""Groups of columns of a measurement table by their names: position-like triples (names that differ
in one x/y/z letter), quaternion quadruples and whether a triple is named as angles. Used by the table
map's suggestion (:mod:`.table_map`) and its orientation part (:mod:`.suggest_orientation`)."""

from __future__ import annotations

import math
import re

__all__ = ["quads", "rotation_triple", "triples"]

_AXES = "xyz"


def triples(header: list[str]) -> list[tuple[str, str, str]]:
    """Column triples whose names differ only in one x/y/z letter (any case), in header order."""
    out, seen = [], set()
    for h in header:
        for m in re.finditer(r"(?<![A-Za-z])[xX](?![A-Za-z])|[xX]$|^[xX]", h):
            i = m.start()
            trip = [h[:i] + (a.upper() if h[i].isupper() else a) + h[i + 1:] for a in _AXES]
            if all(t in header for t in trip) and h not in seen:
                out.append(tuple(trip))
                seen.update(trip)
                break
    return out


def quads(header: list[str], values=None) -> list[tuple[str, str, str, str]]:
    """Quaternion columns, scalar first: ``qw..qz``-like names (w, x, y, z, with q/quat/rot/ori in the
    name: Motive's ``"Tool Rotation W"``), Leica's ``Q0, QX, QY, QZ`` and ``q0..q3``; the last only
    when the sample rows (``values(column)``) have unit norm (else they are joints)."""
    out = []

    def unit(cand):
        if values is None:
            return False
        v = [values(c, signed=True) for c in cand]
        n = min(len(x) for x in v)
        return n > 0 and all(abs(math.sqrt(sum(x[i] ** 2 for x in v)) - 1.0) < 1e-3 for i in range(n))

    for h in header:
        for m in re.finditer(r"[wW]", h):
            i = m.start()
            cand = [h[:i] + (a.upper() if h[i].isupper() else a) + h[i + 1:] for a in "wxyz"]
            if all(c in header for c in cand) and re.search(r"(?i)q|quat|rot|ori", h):
                out.append(tuple(cand))
                break
        for m in re.finditer(r"0", h):
            i = m.start()
            for axes in ("XYZ", "xyz", "123"):
                cand = [h] + [h[:i] + a + h[i + 1:] for a in axes]
                if all(c in header for c in cand) and re.search(r"(?i)q|quat|rot|ori", h) and (axes != "123" or unit(cand)):
                    out.append(tuple(cand))
                    break
    return out


_ROT_WORDS = {"r", "rot", "rotation", "rotations", "angle", "angles", "ang", "euler", "ori", "orient", "orientation", "rv",
              "rotvec", "helical", "q", "quat", "quaternion"}


def rotation_triple(t) -> bool:
    """A triple named as angles (Vicon ``RX``, ``Rot X``, ``Tool Rotation X``, Leica ``QX``), never a position."""
    h, k = t[0], 0
    for k in range(len(h)):
        if h[k] in "xX" and t[1] == h[:k] + ("Y" if h[k] == "X" else "y") + h[k + 1:]:
            break
    stem = re.sub(r"([a-z])([A-Z])", r"\1 \2", h[:k] + " " + h[k + 1:])
    return any(w.lower() in _ROT_WORDS for w in re.findall(r"[A-Za-z]+", stem))
