"""SiLU and sigmoid over a row of activations, compiled and vectorised: the networks' exp-based
activations without a libm call per element.

numba compiles ``math.exp`` to one scalar libm call per element (no SIMD math library in llvmlite's
builds), and numpy's float64 ``exp`` is scalar on AVX2 machines too: the activations took ~1.7 µs of a
default network's ~3.7 µs evaluation in the compiled kernel (:mod:`hykin.hybrid.fast_fk`) and over half
of the numpy path's time (:mod:`hykin.hybrid.fast_nets`). Here ``exp`` is the textbook reduction
``x = t ln2 + r`` (``|r| <= ln2 / 2``, ``ln2`` split in two parts so that ``t ln2`` is exact), the
degree-12 Taylor polynomial of ``e^r`` in Estrin's form (truncation below 2e-16 relative; four levels
deep instead of twelve, so that the out-of-order core overlaps elements), and ``2^t`` built in the
exponent bits. Three plain loops over the row, which LLVM vectorises: the loop without the exponent
bits would need a float -> int64 conversion that AVX2 lacks.

Arguments are clamped to ``[-700, 700]`` first (``e^±700`` is finite): where numpy's ``exp``
overflows, SiLU gives ``x / (1 + 1e304)`` ≈ −7e-302 instead of −0 and sigmoid 1e-304 instead of 0.
Otherwise within 1e-15 relative of ``x / (1 + np.exp(-x))`` (tested), so the compiled and numpy
paths still agree with the torch float64 path to rounding.
"""

from __future__ import annotations

import math

import numpy as np

from ..kinematics.fk import HAVE_NUMBA

__all__ = ["ACT_CODES", "act_rows", "act_vec"]

#: activation name -> the code the compiled networks use (:func:`hykin.hybrid.fast_fk.pack_net`)
ACT_CODES = {None: 0, "relu": 1, "silu": 2, "gelu": 3, "tanh": 4, "sigmoid": 5}

_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01  # ln 2 to 32 bits: t * _LN2_HI is exact for |t| < 2^21
_LN2_LO = 1.90821492927058770002e-10
_ROUND = 6755399441055744.0  # 1.5 * 2^52: adding it rounds to an integer held in the low mantissa bits
_ROUND_BITS = int(np.array([_ROUND]).view(np.int64)[0])
_C = tuple(1.0 / math.factorial(i) for i in range(13))

if HAVE_NUMBA:
    import numba

    _c0, _c1, _c2, _c3, _c4, _c5, _c6, _c7, _c8, _c9, _c10, _c11, _c12 = _C

    @numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
    def _exp_r(x, t):  # pragma: no cover - compiled
        """``e^(x - t ln2)`` for ``|x - t ln2| <= ln2 / 2`` (Estrin's scheme)."""
        y = (x - t * _LN2_HI) - t * _LN2_LO
        y2 = y * y
        y4 = y2 * y2
        b0 = (_c0 + _c1 * y) + (_c2 + _c3 * y) * y2
        b1 = (_c4 + _c5 * y) + (_c6 + _c7 * y) * y2
        b2 = (_c8 + _c9 * y) + (_c10 + _c11 * y) * y2
        return (b0 + b1 * y4) + (b2 + _c12 * y4) * (y4 * y4)

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def act_vec(a, y, n, f, nb):  # pragma: no cover - compiled
        """``y[:n] = act(y[:n])`` in place for activation code ``a`` (:data:`ACT_CODES`); ``f`` float64
        and ``nb`` int64 scratch of at least ``n`` (SiLU and sigmoid use them)."""
        if a == 2 or a == 5:
            for k in range(n):
                f[k] = min(max(-y[k], -700.0), 700.0) * _LOG2E + _ROUND  # t = round(-y log2 e), in f's bits
            fb = f[:n].view(np.int64)
            for k in range(n):
                nb[k] = (fb[k] - _ROUND_BITS + 1023) << 52  # 2^t as float64 bits
            sc = nb[:n].view(np.float64)
            if a == 2:
                for k in range(n):
                    x = min(max(-y[k], -700.0), 700.0)
                    y[k] = y[k] / (1.0 + _exp_r(x, f[k] - _ROUND) * sc[k])
            else:
                for k in range(n):
                    x = min(max(-y[k], -700.0), 700.0)
                    y[k] = 1.0 / (1.0 + _exp_r(x, f[k] - _ROUND) * sc[k])
        elif a == 1:
            for k in range(n):
                y[k] = y[k] if y[k] > 0.0 else 0.0
        elif a == 3:
            for k in range(n):
                y[k] = 0.5 * y[k] * (1.0 + math.erf(y[k] / math.sqrt(2.0)))
        elif a == 4:
            for k in range(n):
                y[k] = math.tanh(y[k])

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def _act_rows(a, h, f, nb):  # pragma: no cover - compiled
        act_vec(a, h.reshape(-1), h.size, f, nb)


def act_rows(act: str, h: np.ndarray, scratch: dict) -> bool:
    """``h = act(h)`` in place on a C-contiguous float64 block with the compiled :func:`act_vec` for
    SiLU and sigmoid; returns False (nothing done) for other activations or without numba."""
    if not HAVE_NUMBA or act not in ("silu", "sigmoid") or not h.flags.c_contiguous:
        return False
    f, nb = scratch.get("act_f"), scratch.get("act_i")
    if f is None or f.size < h.size:
        f, nb = scratch["act_f"], scratch["act_i"] = np.empty(h.size), np.empty(h.size, dtype=np.int64)
    _act_rows(ACT_CODES[act], h, f, nb)
    return True
