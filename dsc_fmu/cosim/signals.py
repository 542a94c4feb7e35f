"""The columns of a result: what is recorded from each FMU, what is derived, and their units."""

from __future__ import annotations

import numpy as np

from ..models.controller import wrap
from ..registry import CONTROLLER, FMUS, ORDER, PLANT

__all__ = ["RECORDED", "COUNTS", "DERIVED", "COLUMNS", "UNITS", "DTYPE"]

COUNTS = {PLANT: "saturation_count", CONTROLLER: "beta_guard_count"}
"""The Integer output recorded from an FMU besides its Real outputs, by FMU name."""

RECORDED = {
    name: (*(v.name for v in FMUS[name].outputs), *((COUNTS[name],) if name in COUNTS else ())) for name in ORDER
}

DERIVED = ("xe", "ye", "thetae", "position_error")

_FIRST = (
    "x", "y", "theta", "x_r", "y_r", "theta_r", "xe", "ye", "thetae", "position_error",
    "u1", "u2", "omega1", "omega2", "i1", "i2", "a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm",
)
COLUMNS = (
    "time",
    *_FIRST,
    *(name for names in RECORDED.values() for name in names if name not in _FIRST),
)

UNITS = {
    "time": "s", "xe": "m", "ye": "m", "thetae": "rad", "position_error": "m",
    **{name: "1" for name in COUNTS.values()},
    **{v.name: v.unit for name in ORDER for v in FMUS[name].outputs},
}

DTYPE = np.dtype([(name, np.float64) for name in COLUMNS])


def add_tracking_errors(result: np.ndarray) -> None:
    """Set a result's tracking errors in place (docs/model.md §5): ``xe = x_r - x``, ``ye = y_r - y`` (m),
    ``thetae = wrap(theta_r - theta)`` (rad), ``position_error = hypot(xe, ye)`` (m)."""
    result["xe"] = result["x_r"] - result["x"]
    result["ye"] = result["y_r"] - result["y"]
    result["thetae"] = [wrap(a) for a in result["theta_r"] - result["theta"]]
    result["position_error"] = np.hypot(result["xe"], result["ye"])
