"""Analysis of a step-size sweep: observed convergence order, stability boundary, and sweep.json."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

__all__ = ["DEVIATION_QUANTITIES", "AGREEMENT_TOLERANCE", "OrderFit", "fit_order"]

DEVIATION_QUANTITIES = ("max_position_deviation_m", "max_heading_deviation_rad", "max_u_deviation_V")
AGREEMENT_TOLERANCE = 0.2  # predicted and measured boundary agree if |predicted / measured - 1| <= 20 %


@dataclass(frozen=True)
class OrderFit:
    """A straight line ``log10(deviation) = intercept + slope * log10(h)`` through the asymptotic range.

    Parameters
    ----------
    slope : float
        The observed convergence order p: deviation ~ ``10**intercept * h**p``.
    intercept : float
        log10 of the deviation at h = 1 s, in log10 of the fitted data's unit.
    h_min, h_max : float
        The smallest and largest step in the fitted range, in s.
    points : int
        The number of steps in the fitted range.
    max_residual : float
        The largest |residual| in log10 (0.03 is a factor 1.07).
    r2 : float
        The coefficient of determination in log-log.
    """

    slope: float
    intercept: float
    h_min: float
    h_max: float
    points: int
    max_residual: float
    r2: float

    def deviation(self, step_size):
        """The fitted deviation at a step size.

        Parameters
        ----------
        step_size : float or array_like
            Communication step(s) h, in s.

        Returns
        -------
        numpy.ndarray or numpy.float64
            ``10**intercept * h**slope``, in the unit of the fitted data, shaped like ``step_size``.
        """
        return 10.0**self.intercept * np.asarray(step_size, dtype=float) ** self.slope


@dataclass(frozen=True)
class Boundary:
    """A stability boundary bracketed by ``h_stable`` < h* <= ``h_unstable`` (s), the estimate ``h_stable``;
    ``evaluated``: the ``(step_size, stable)`` pairs run during the refinement, in the order run."""

    h_stable: float
    h_unstable: float
    evaluated: tuple[tuple[float, bool], ...] = ()

    @property
    def estimate(self) -> float:
        """The estimate of the boundary h*, in s: ``h_stable``."""
        return self.h_stable

    @property
    def relative_width(self) -> float:
        """The bracket's width relative to its lower end, ``(h_unstable - h_stable) / h_stable``."""
        return (self.h_unstable - self.h_stable) / self.h_stable


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float, np.ndarray]:
    slope, intercept = np.polyfit(x, y, 1)
    return float(slope), float(intercept), y - (intercept + slope * x)


def fit_order(step_sizes: Sequence[float], deviations: Sequence[float], *, tolerance: float = 0.03,
              min_points: int = 3) -> OrderFit:
    """The observed convergence order over the asymptotic range of small steps.

    A least-squares line of log10(deviation) against log10(h). Points whose deviation is NaN, None,
    infinite or not positive (diverged runs) are left out. The range starts with the ``min_points``
    smallest steps and grows toward larger h while the line keeps every point within ``tolerance``;
    it stops at the first step that breaks the line (the knee where higher-order terms or instability
    take over), even if larger steps would fall back onto it. If the smallest steps are not on a line
    (a floor set by the reference solution's own accuracy), the start moves up one step at a time.

    Parameters
    ----------
    step_sizes : sequence of float
        Communication steps h, in s, distinct.
    deviations : sequence of float
        The deviation at each step, same length, in any unit (e.g. m).
    tolerance : float, optional
        The largest |residual| allowed in log10. Default 0.03 (a factor 1.07).
    min_points : int, optional
        The fewest steps a range may have, at least 2. Default 3.

    Returns
    -------
    OrderFit
        The line through the range found; its ``slope`` is the order.

    Raises
    ------
    ValueError
        If the inputs are not 1-D of equal length, ``min_points`` < 2, step sizes repeat, fewer than
        ``min_points`` usable points remain or no ``min_points`` consecutive points lie on a line.

    Examples
    --------
    >>> fit = fit_order([1e-3, 2e-3, 4e-3, 8e-3], [0.5e-3, 1e-3, 2e-3, 4e-3])
    >>> round(fit.slope, 9), fit.h_min, fit.h_max, fit.points
    (1.0, 0.001, 0.008, 4)
    """
    h = np.asarray(step_sizes, dtype=float)
    d = np.asarray(deviations, dtype=float)
    if h.ndim != 1 or h.shape != d.shape:
        raise ValueError(f"step_sizes and deviations must be 1-D of equal length; got shapes {h.shape} and {d.shape}")
    if min_points < 2:
        raise ValueError(f"min_points = {min_points} is not allowed; allowed: >= 2")
    usable = np.isfinite(h) & (h > 0) & np.isfinite(d) & (d > 0)
    h, d = h[usable], d[usable]
    if len(h) < min_points:
        raise ValueError(f"{len(h)} usable points (finite, positive deviation) of {len(usable)}; "
                         f"a convergence order needs at least {min_points}")
    sort = np.argsort(h, kind="stable")
    h, d = h[sort], d[sort]
    x, y = np.log10(h), np.log10(d)
    if np.any(np.diff(x) == 0):
        raise ValueError(f"step sizes must be distinct; got {sorted(h.tolist())} (average repeated runs first)")
    n = len(x)
    for start in range(n - min_points + 1):
        stop = start + min_points
        if np.abs(_line(x[start:stop], y[start:stop])[2]).max() >= tolerance:
            continue
        while stop < n and np.abs(_line(x[start:stop + 1], y[start:stop + 1])[2]).max() < tolerance:
            stop += 1
        xs, ys = x[start:stop], y[start:stop]
        slope, intercept, residual = _line(xs, ys)
        total = float(np.sum((ys - ys.mean()) ** 2))
        return OrderFit(slope=slope, intercept=intercept, h_min=float(h[start]), h_max=float(h[stop - 1]),
                        points=stop - start, max_residual=float(np.abs(residual).max()),
                        r2=1.0 if total == 0 else 1.0 - float(np.sum(residual**2)) / total)
    raise ValueError(f"no {min_points} consecutive step sizes of {n} lie on a straight line in log-log "
                     f"within {tolerance} (log10): no asymptotic range")


def grid_bracket(step_sizes: Sequence[float], stable_flags: Sequence[bool]) -> tuple[float, float] | None:
    """The grid's bracket ``(h_stable, h_unstable)`` (s): the smallest unstable step and the largest stable
    one below it; None if every step is stable or none below the first unstable one is. Stability need
    not be monotone in h: the bracket is around the first loss of stability. A step that appears more
    than once (samples, overrides) counts as stable only if all its runs are.

    >>> grid_bracket([0.001, 0.002, 0.005, 0.01], [True, True, False, True])
    (0.002, 0.005)
    """
    if len(step_sizes) != len(stable_flags):
        raise ValueError(f"{len(step_sizes)} step sizes but {len(stable_flags)} stability flags")
    stable: dict[float, bool] = {}
    for h, flag in zip(step_sizes, stable_flags):
        stable[float(h)] = stable.get(float(h), True) and bool(flag)
    steps = sorted(stable)
    first = next((i for i, h in enumerate(steps) if not stable[h]), None)
    if first is None or first == 0:
        return None
    return steps[first - 1], steps[first]


def refine_boundary(is_stable: Callable[[float], bool], h_stable: float, h_unstable: float,
                    rel_tol: float = 0.02) -> Boundary:
    """Bisect the bracket (s) at geometric midpoints, running ``is_stable(h)`` at each, until
    ``(h_unstable - h_stable) / h_stable <= rel_tol``: ``ceil(log2(ln(h_unstable / h_stable) / ln(1 +
    rel_tol)))`` evaluations. If stability is not monotone in h, the result is one transition from
    stable to unstable inside the bracket. ValueError unless ``0 < h_stable < h_unstable``, ``rel_tol > 0``.
    """
    if not 0 < h_stable < h_unstable:
        raise ValueError(f"bracket ({h_stable!r}, {h_unstable!r}) is not allowed; allowed: 0 < h_stable < h_unstable")
    if not rel_tol > 0:
        raise ValueError(f"rel_tol = {rel_tol!r} is not allowed; allowed: > 0")
    h_stable, h_unstable = float(h_stable), float(h_unstable)
    evaluated = []
    while (h_unstable - h_stable) / h_stable > rel_tol:
        h = math.sqrt(h_stable * h_unstable)
        stable = bool(is_stable(h))
        evaluated.append((h, stable))
        if stable:
            h_stable = h
        else:
            h_unstable = h
    return Boundary(h_stable, h_unstable, tuple(evaluated))


def overrides(row: Mapping) -> dict:
    """The parameter overrides of a sweep row: its items whose key has a dot, like ``controller.k4``."""
    return {name: value for name, value in row.items() if "." in name}


def _value(value) -> str:
    return f"{value:g}" if isinstance(value, (int, float, np.number)) and not isinstance(value, bool) else str(value)


def group_label(row: Mapping) -> str:
    """The label of a row's series: ``order/discretization``, the coupling if not the hold,
    ``error-controlled`` for a run with a tolerance, any overrides ``name=value``, ``sample N``; e.g.
    ``gauss-seidel/rk4 linear controller.k4=2 sample 3``."""
    parts = [f"{row['order']}/{row.get('discretization', 'rk4')}"]
    if row.get("coupling", "hold") != "hold":
        parts.append(row["coupling"])
    if row.get("tolerance") is not None:
        parts.append("error-controlled")
    parts += [f"{name}={_value(value)}" for name, value in sorted(overrides(row).items())]
    if row.get("sample") is not None:
        parts.append(f"sample {row['sample']}")
    return " ".join(parts)


def group_rows(rows: Sequence[Mapping]) -> dict[str, list[Mapping]]:
    """The rows of a sweep by ``group_label``, each series sorted by step size."""
    groups: dict[str, list[Mapping]] = {}
    for row in rows:
        groups.setdefault(group_label(row), []).append(row)
    return {label: sorted(group, key=lambda row: row["step_size"]) for label, group in groups.items()}


def _float(value) -> float:
    return math.nan if value is None else float(value)


def fit_orders(rows: Sequence[Mapping], quantities: Sequence[str] = DEVIATION_QUANTITIES,
               **fit_options) -> dict[str, dict[str, OrderFit | str]]:
    """``group_label`` -> quantity -> OrderFit (``fit_order`` with ``fit_options``), or the ValueError's
    message if no order could be fitted."""
    fits: dict[str, dict[str, OrderFit | str]] = {}
    for label, group in group_rows(rows).items():
        fits[label] = {}
        for quantity in quantities:
            try:
                fits[label][quantity] = fit_order([row["step_size"] for row in group],
                                                  [_float(row.get(quantity)) for row in group], **fit_options)
            except ValueError as error:
                fits[label][quantity] = str(error)
    return fits


def grid_brackets(rows: Sequence[Mapping]) -> dict[str, tuple[float, float] | None]:
    """The grid's stability bracket of each series of a sweep."""
    return {label: grid_bracket([row["step_size"] for row in group], [row["stable"] for row in group])
            for label, group in group_rows(rows).items()}


def _stability(group: Sequence[Mapping], boundary: Boundary | None) -> dict:
    steps = sorted({float(row["step_size"]) for row in group})
    bracket = grid_bracket([row["step_size"] for row in group], [row["stable"] for row in group])
    result = {"grid_bracket_s": list(bracket) if bracket else None, "refined": None, "estimate_s": None}
    if boundary is not None:
        result["refined"] = {"h_stable_s": boundary.h_stable, "h_unstable_s": boundary.h_unstable,
                             "relative_width": boundary.relative_width,
                             "evaluated": [{"step_size": h, "stable": s} for h, s in boundary.evaluated]}
        result["estimate_s"] = boundary.h_stable
        result["status"] = "refined"
        result["message"] = (f"stable up to {boundary.h_stable:.3g} s, unstable at {boundary.h_unstable:.3g} s "
                             f"(refined in {len(boundary.evaluated)} runs)")
    elif bracket is not None:
        result["estimate_s"] = bracket[0]
        result["status"] = "grid"
        result["message"] = f"stable up to {bracket[0]:.3g} s, unstable at {bracket[1]:.3g} s (grid only, not refined)"
    elif all(row["stable"] for row in group):
        result["status"] = "all stable"
        result["message"] = f"no boundary within the grid: every step up to {steps[-1]:.3g} s is stable"
    else:
        result["status"] = "none stable"
        result["message"] = f"no boundary within the grid: already unstable at the smallest step {steps[0]:.3g} s"
    result["grid_range_s"] = [steps[0], steps[-1]]
    return result


def _comparison(stability: dict, predicted: float | None, tolerance: float) -> dict:
    result = {"predicted_boundary_s": predicted, "ratio_predicted_to_measured": None, "agrees": None}
    low, high = stability["grid_range_s"]
    if predicted is None:
        result["statement"] = "no prediction"
    elif stability["estimate_s"] is not None:
        ratio = predicted / stability["estimate_s"]
        result["ratio_predicted_to_measured"] = ratio
        result["agrees"] = abs(ratio - 1.0) <= tolerance
        result["statement"] = (f"predicted {predicted:.3g} s, measured {stability['estimate_s']:.3g} s: ratio "
                               f"{ratio:.3g}, " + (f"agreeing within {tolerance:.0%}" if result["agrees"] else
                                                   f"more than {tolerance:.0%} apart"))
    elif stability["status"] == "all stable":
        result["agrees"] = predicted > high * (1.0 - tolerance)
        result["statement"] = (f"predicted {predicted:.3g} s, every measured step up to {high:.3g} s stable: "
                               + ("consistent" if result["agrees"] else "the prediction is too small"))
    else:
        result["agrees"] = predicted < low * (1.0 + tolerance)
        result["statement"] = (f"predicted {predicted:.3g} s, already unstable at the smallest step {low:.3g} s: "
                               + ("consistent" if result["agrees"] else "the prediction is too large"))
    return result


def summarise(rows: Sequence[Mapping], *, stability_definition: str, settings: Mapping | None = None,
              fits: Mapping[str, Mapping[str, OrderFit | str]] | None = None,
              boundaries: Mapping[str, Boundary | None] | None = None,
              predictions: Mapping[str, float | None] | None = None, notes: Sequence[str] = (),
              tolerance: float = AGREEMENT_TOLERANCE) -> dict:
    """The content of ``sweep.json`` (JSON-serialisable, NaN and infinities as None): per series its order,
    discretization, overrides and sample, counts, observed orders (``fits``, else fitted here), stability
    boundary (``boundaries`` by ``group_label``, else the grid bracket) and the comparison with the
    prediction (``predictions``: h* in s by ``group_label``, or by coupling order for the series with
    nominal parameters), agreeing if ``|predicted / measured - 1| <= tolerance``.
    """
    fits = fit_orders(rows) if fits is None else fits
    boundaries, predictions = boundaries or {}, predictions or {}
    groups = {}
    for label, group in group_rows(rows).items():
        first = group[0]
        stability = _stability(group, boundaries.get(label))
        nominal = not overrides(first) and first.get("sample") is None
        predicted = predictions.get(label, predictions.get(first["order"]) if nominal else None)
        groups[label] = {
            "order": first["order"], "discretization": first.get("discretization"),
            "overrides": overrides(first), "sample": first.get("sample"),
            "runs": len(group), "diverged": sum(bool(row["diverged"]) for row in group),
            "unstable": sum(not row["stable"] for row in group),
            "step_sizes_s": sorted({float(row["step_size"]) for row in group}),
            "observed_order": {quantity: asdict(fit) if isinstance(fit, OrderFit) else {"error": fit}
                               for quantity, fit in fits.get(label, {}).items()},
            "stability_boundary": stability,
            "prediction": _comparison(stability, None if predicted is None else float(predicted), tolerance),
        }
    return to_json({
        "scenario": ", ".join(sorted({str(row["scenario"]) for row in rows})),
        "settings": dict(settings or {}),
        "stability_definition": stability_definition,
        "agreement_tolerance": tolerance,
        "counts": {"runs": len(rows), "diverged": sum(bool(row["diverged"]) for row in rows),
                   "unstable": sum(not row["stable"] for row in rows)},
        "groups": groups,
        "notes": list(notes),
    })


def to_json(value):
    """``value`` as strict JSON takes it: keys as strings, NumPy values as Python's, tuples as lists, Paths as
    strings, NaN and infinities as None."""
    if isinstance(value, Mapping):
        return {str(key): to_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [to_json(item) for item in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def write_summary_json(out_dir: Path | str, summary: Mapping) -> Path:
    """Write a sweep's summary to ``sweep.json``."""
    path = Path(out_dir) / "sweep.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_json(summary), indent=2, allow_nan=False) + "\n")
    return path
