"""Tracking metrics of a result: errors over the last third of the run, settling time, peak voltage."""

from __future__ import annotations

import numpy as np

__all__ = ["SETTLING_THRESHOLD", "tracking_metrics"]

SETTLING_THRESHOLD = 0.1  # m


def settling_time(time: np.ndarray, error: np.ndarray, threshold: float) -> float | None:
    """The first row time (s) from which every ``error`` is below ``threshold`` (NaN is not); None if the last is not."""
    above = np.flatnonzero(~(np.asarray(error) < threshold))  # NaN counts as not settled
    if len(above) == 0:
        return float(time[0])
    if above[-1] == len(error) - 1:
        return None
    return float(time[above[-1] + 1])


def tracking_metrics(result: np.ndarray, stop_time: float) -> dict:
    """Tracking metrics of a result: errors over its last third, settling time, peak voltage.

    Parameters
    ----------
    result : numpy.ndarray
        Rows with the columns of ``signals.COLUMNS``.
    stop_time : float
        Where the result ends, in s.

    Returns
    -------
    dict
        JSON-serialisable. Over the rows in [2/3 stop_time, stop_time] (``window_start_s``, ``window_end_s``):
        the position error ``sqrt(xe^2 + ye^2)``'s ``final_position_error_m``, ``rms_position_error_m`` and
        ``max_position_error_m``, and ``max_abs_thetae_rad``. Over the whole run: ``settling_time_0p1_s``
        (from when the position error stays below 0.1 m, None if never), ``max_abs_u_V`` and
        ``beta_guard_count`` (steps in which the controller's beta guard acted).

    Raises
    ------
    ValueError
        If ``stop_time`` is not positive or no row lies in the window.
    """
    if not stop_time > 0:
        raise ValueError(f"stop_time = {stop_time!r} is not allowed; allowed: > 0")
    time = result["time"]
    start = 2.0 * stop_time / 3.0
    window = time >= start - 1e-9 * stop_time
    if not window.any():
        raise ValueError(f"no row recorded in the window [{start:g}, {stop_time:g}] s")
    error = result["position_error"][window]
    return {
        "window_start_s": start,
        "window_end_s": float(stop_time),
        "final_position_error_m": float(error[-1]),
        "rms_position_error_m": float(np.sqrt(np.mean(error**2))),
        "max_position_error_m": float(np.max(error)),
        "max_abs_thetae_rad": float(np.max(np.abs(result["thetae"][window]))),
        "settling_time_0p1_s": settling_time(time, result["position_error"], SETTLING_THRESHOLD),
        "max_abs_u_V": float(max(np.max(np.abs(result["u1"])), np.max(np.abs(result["u2"])))),
        "beta_guard_count": int(result["beta_guard_count"][-1]),
    }
