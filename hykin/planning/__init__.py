"""Measurement planning: which poses to measure, in which order, and how many (``hykin plan``).

Modules: :mod:`.constraints` (region, Cartesian box, tracker line of sight, keep-out boxes),
:mod:`.criteria` (identifiability of the calibration parameters), :mod:`.coverage` (space-filling
in the networks' joint coordinates), :mod:`.select` (D-optimal core + space-filling fill; active
selection for a fitted model), :mod:`.order` (short measuring path), :mod:`.forecast` (accuracy
against the number of poses). The method is described in ``docs/planning.md``.
"""

from .constraints import (
    Constraints,
    PlanningError,
    feasible,
    incidence_deg,
    parse_box,
    parse_region,
    region_bounds,
)
from .coverage import coverage_report, embed, farthest_point, fill_distance
from .criteria import identification_model, observability, scaled_rows
from .forecast import Forecast, forecast_accuracy
from .order import order_path, path_travel
from .select import Plan, active_poses, d_optimal, plan_poses

__all__ = [
    "Constraints",
    "Forecast",
    "Plan",
    "PlanningError",
    "active_poses",
    "coverage_report",
    "d_optimal",
    "embed",
    "farthest_point",
    "feasible",
    "fill_distance",
    "forecast_accuracy",
    "identification_model",
    "incidence_deg",
    "observability",
    "order_path",
    "parse_box",
    "parse_region",
    "path_travel",
    "plan_poses",
    "region_bounds",
    "scaled_rows",
]
