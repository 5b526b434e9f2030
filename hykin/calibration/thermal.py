"""Thermal expansion of the arm: one linear coefficient, identified from a temperature column.

A robot's links (and tool) expand with temperature: about 11.5e-6 /K for steel, 23e-6 /K for
aluminium, i.e. 0.02 mm per kelvin at a 1.5 m reach. Measurement sessions warm up by several
kelvin, so this is an error the joints cannot explain: a model of q alone can only average it out.
When the data carry the temperature (a ``temperature_c`` or ``temperature`` column, °C, kept as an
extra column by :mod:`hykin.io.dataset`), uniform expansion of every length of the chain is modelled
exactly: the pose at temperature ``t`` is the pose at the reference temperature ``t_ref`` with its
position scaled about the robot base origin ``b``,

    p(t) = b + (1 + alpha (t - t_ref)) (p(t_ref) - b),    orientation unchanged,

``alpha`` (1/K) being identified together with the calibration (alternating: fit ``alpha`` on the
calibrated residuals, map the measurements to ``t_ref``, recalibrate), as the maximum a posteriori
under the prior ``0 ± thermal_per_k`` (:mod:`hykin.calibration.priors`: the robot file has no
expansion). The coefficient is kept only when it is significant (``|alpha| >= 3 std``), physical
(``0 < alpha <= 60e-6 /K``: a steel or aluminium arm expands, by 11.5e-6 or 23e-6 /K) and not
negligible (``alpha`` x temperature std x RMS reach >= 0.5 µm); otherwise the model ignores
temperature.

**Physics with signs.** A significant coefficient outside ``(0, 60e-6]`` /K (a negative one: the arm
"shrinking" as it warms; or three times aluminium's) is not the arm: it is the instrument drifting
with the session (a laser tracker's frame or wavelength compensation), which a temperature column
happens to track. Such a coefficient is dropped with ONE warning line saying so, and the model is
fitted without temperature, never refused: the robot file and the data are correct, only the
thermal term is not the arm's (a refusal would turn away a correct input). With ``thermal=True``
the same holds (the column is required, a non-physical coefficient is still not applied). On the real UR10 series A (laser tracker, 22.9-23.7 °C,
std 0.17 K) it is not significant (-1.5e-5 +- 1.3e-5 /K) and so not used.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = [
    "DRIFT_WARNING",
    "TEMPERATURE_COLUMNS",
    "ThermalFit",
    "fit_coefficient",
    "scale_about",
    "temperature_from",
    "temperature_of",
    "to_reference",
]

#: extra columns read as the temperature (°C), in order of preference
TEMPERATURE_COLUMNS = ("temperature_c", "temperature")
#: largest plausible linear expansion coefficient (1/K); aluminium is 23e-6, magnesium 26e-6
MAX_PLAUSIBLE_PER_K = 60e-6
#: the one warning line when the data show a coefficient no arm has
DRIFT_WARNING = ("thermal: the data show {alpha:.2g} /K ({why}): drift of the instrument, not expansion of the arm; "
                 "temperature ignored")
#: smallest effect worth a coefficient: alpha x temperature std x RMS reach (m)
MIN_EFFECT_M = 0.5e-6


@dataclasses.dataclass
class ThermalFit:
    """Identified expansion: ``coefficient_per_k`` (1/K, 0 when not kept), its ``std_per_k``,
    ``reference_c`` (°C), the training range ``range_c`` (min, max) and ``note`` (why it was kept
    or not)."""

    coefficient_per_k: float
    std_per_k: float
    reference_c: float
    range_c: tuple[float, float]
    note: str

    def to_dict(self) -> dict:
        return {"coefficient_per_k": self.coefficient_per_k, "std_per_k": self.std_per_k,
                "reference_c": self.reference_c, "range_c": list(self.range_c), "note": self.note}


#: °C a robot cell (and a robot's structure in it) stays within; beyond: kelvin or °F, not Celsius. A
#: room at 68-95 °F reads 20-35 in °C too; those rows are inside and cannot be told from Celsius.
MIN_CELL_C, MAX_CELL_C = -40.0, 80.0


def temperature_from(extra: dict, where: str = "<dataset>") -> np.ndarray | None:
    """The temperature column (°C, ``(N,)`` float64) among extra columns ``{name: (N,)}``, or None.
    Raises ``ValueError`` naming the file, column and row on a non-numeric or non-finite value."""
    for name in TEMPERATURE_COLUMNS:
        if name in (extra or {}):
            try:
                t = np.asarray(extra[name], dtype=np.float64).reshape(-1)
            except (TypeError, ValueError):
                raise ValueError(f"{where}: column '{name}' is not numeric (temperature, °C)") from None
            bad = ~np.isfinite(t)
            if bad.any():
                raise ValueError(f"{where}: column '{name}', row {int(np.argmax(bad)) + 1}: non-finite temperature")
            hot = (t > MAX_CELL_C) | (t < MIN_CELL_C)
            if hot.any():
                r = int(np.argmax(hot))
                unit = "kelvin (subtract 273.15)" if t[r] > 200 else "°F (°C = (°F - 32) / 1.8)" if t[r] > MAX_CELL_C else "not °C"
                raise ValueError(f"{where}: column '{name}', row {r + 1}: {t[r]:g} °C is outside what a robot cell sees "
                                 f"({MIN_CELL_C:g} to {MAX_CELL_C:g} °C): the values look like {unit}")
            return t
    return None


def temperature_of(ds) -> np.ndarray | None:
    """The temperature column of a Dataset (see :func:`temperature_from`), or None."""
    return temperature_from(getattr(ds, "extra", None) or {}, getattr(ds, "source", "") or "<dataset>")


def scale_about(T: np.ndarray, origin_m: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """Poses ``T`` ``(N, 4, 4)`` with positions scaled by ``factor`` ``(N,)`` about ``origin_m`` ``(3,)``
    (a copy; rotations unchanged)."""
    out = np.array(T, dtype=np.float64, copy=True)
    out[:, :3, 3] = origin_m + factor[:, None] * (out[:, :3, 3] - origin_m)
    return out


def fit_coefficient(xyz_meas_m: np.ndarray, xyz_model_m: np.ndarray, origin_m: np.ndarray, dtemp_k: np.ndarray,
                    alpha0: float, tolerance_per_k: float = float("inf")) -> tuple[float, float]:
    """Least-squares (MAP with a prior) update of ``alpha`` given model positions at the reference temperature.

    ``xyz_meas_m`` measured ``(N, 3)``; ``xyz_model_m`` the model's ``(N, 3)`` at ``t_ref`` when the
    data were mapped with ``alpha0``; ``dtemp_k`` ``t - t_ref`` ``(N,)``; ``tolerance_per_k``: prior
    standard deviation of ``alpha`` about 0 (inf: plain least squares). Returns ``(alpha, std)``
    (posterior std; the noise per coordinate from the least-squares residual).
    """
    g = dtemp_k[:, None] * (xyz_model_m - origin_m)  # d p / d alpha
    r = xyz_meas_m - (origin_m + (1.0 + alpha0 * dtemp_k)[:, None] * (xyz_model_m - origin_m))
    gg = float(np.sum(g * g))
    if gg <= 0:
        return 0.0, float("inf")
    gr = float(np.sum(g * r))
    res = r - (gr / gg) * g
    dof = max(r.size - 1, 1)
    sigma2 = float(np.sum(res * res)) / dof
    prec = sigma2 / tolerance_per_k ** 2 if np.isfinite(tolerance_per_k) and tolerance_per_k > 0 else 0.0
    step = (gr - prec * alpha0) / (gg + prec)  # pulls alpha0 + step toward the prior mean 0
    return alpha0 + step, float(np.sqrt(sigma2 / (gg + prec)))


def to_reference(ds, origin_m: np.ndarray, alpha: float, dtemp_k: np.ndarray):
    """The Dataset ``ds`` with its measured positions mapped to the reference temperature."""
    s = 1.0 + alpha * dtemp_k
    return dataclasses.replace(ds, xyz_m=origin_m + (ds.xyz_m - origin_m) / s[:, None])
