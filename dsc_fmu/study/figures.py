"""Figures of a step-size sweep: deviation and fitted order, tracking and cost, paths, spectral radius."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.transforms import blended_transform_factory

from ..cosim.plots import new_figure
from .analysis import OrderFit, fit_orders, group_rows

__all__: list[str] = []  # the figures of run_sweep and write_report

_MARKERS = {"rk4": "o", "euler": "s"}
_LINESTYLES = {"rk4": "-", "euler": ":"}
_DIVERGED_TOP, _DIVERGED_SPACING = 0.97, 0.025  # axes fractions where each series marks its diverged runs


def _styles(labels: Sequence[str], groups: Mapping[str, Sequence[Mapping]]) -> dict[str, dict]:
    """Colour per series from the default cycle; marker and line style by discretization."""
    styles = {}
    for index, label in enumerate(labels):
        discretization = groups[label][0].get("discretization", "rk4")
        styles[label] = {"color": f"C{index % 10}", "marker": _MARKERS.get(discretization, "^"),
                         "linestyle": _LINESTYLES.get(discretization, "--"),
                         "diverged_y": _DIVERGED_TOP - _DIVERGED_SPACING * (index % 10)}
    return styles


def _values(group: Sequence[Mapping], key: str) -> tuple[np.ndarray, np.ndarray]:
    steps = np.array([row["step_size"] for row in group], dtype=float)
    values = np.array([np.nan if row.get(key) is None else row[key] for row in group], dtype=float)
    return steps, values


def _mark_diverged(axes, group: Sequence[Mapping], style: dict) -> bool:
    """An x near the top edge of ``axes`` (a row per series) at the step of each diverged run; True if any."""
    steps = [row["step_size"] for row in group if row["diverged"]]
    if steps:
        transform = blended_transform_factory(axes.transData, axes.transAxes)
        axes.plot(steps, [style["diverged_y"]] * len(steps), "x", color=style["color"], markersize=9,
                  markeredgewidth=2, transform=transform, clip_on=False)
    return bool(steps)


def _series(axes, group: Sequence[Mapping], key: str, label: str, style: dict) -> None:
    """One series of a sweep: finite positive values of ``key`` as line and markers; runs not
    stable (but not diverged) as open markers; diverged runs as an x at the top edge."""
    steps, values = _values(group, key)
    shown = np.isfinite(values) & (values > 0)
    axes.plot(steps[shown], values[shown], color=style["color"], marker=style["marker"],
              linestyle=style["linestyle"], label=label)
    unstable = np.array([not row["stable"] and not row["diverged"] for row in group]) & shown
    if unstable.any():
        axes.plot(steps[unstable], values[unstable], style["marker"], color="white", markeredgecolor=style["color"],
                  markersize=9, markeredgewidth=1.5)
    _mark_diverged(axes, group, style)


def _without_values(axes, rows: Sequence[Mapping], key: str) -> None:
    """If no run has a finite positive ``key``, say so on ``axes`` and give its log y axis a range."""
    values = np.array([np.nan if row.get(key) is None else row[key] for row in rows], dtype=float)
    if not np.any(np.isfinite(values) & (values > 0)):
        axes.set_ylim(0.1, 1.0)
        axes.text(0.5, 0.5, "no finite value: every run diverged", transform=axes.transAxes, ha="center")


def _headroom(axes, series: int) -> None:
    """Raise the top of a log y axis so the rows of diverged marks of ``series`` series sit above the data."""
    fraction = min(0.05 + _DIVERGED_SPACING * min(series, 10), 0.35)
    low, high = axes.get_ylim()
    if 0 < low < high:  # not if nothing but diverged runs is drawn
        axes.set_ylim(low, high * (high / low) ** (fraction / (1.0 - fraction)))


def _legend_of_marks(axes, any_diverged: bool, any_unstable: bool) -> None:
    """Legend entries for the diverged and unstable marks, in grey, then the legend itself."""
    if any_diverged:
        axes.plot([], [], "x", color="0.3", markersize=9, markeredgewidth=2, label="diverged (at top edge)")
    if any_unstable:
        axes.plot([], [], "o", color="white", markeredgecolor="0.3", markersize=9, label="not stable")
    axes.legend(loc="lower right", fontsize="small")


def _fit_of(fits: Mapping | None, label: str, quantity: str) -> OrderFit | None:
    fit = (fits or {}).get(label, {})
    fit = fit.get(quantity) if isinstance(fit, Mapping) else fit
    return fit if isinstance(fit, OrderFit) else None


def plot_deviation(rows: Sequence[Mapping], fits: Mapping | None, path: Path | str, *,
                   with_voltage: bool = True) -> Path:
    """Plot the deviation from the continuous reference solution against the communication step.

    Log-log against h (s): (a) the max position deviation (m), (b) the max voltage deviation (V). One
    line per series (``study.group_label``); each fitted line dashed over its range, with its slope in
    the legend (``fits`` as from ``fit_orders``, else fitted here); diverged runs as an x at the top edge,
    runs not stable as open markers; (b) only ``with_voltage``.

    Writes and returns ``path`` (its suffix sets the format).
    """
    groups = group_rows(rows)
    fits = fit_orders(rows) if fits is None else fits
    styles = _styles(list(groups), groups)
    panels = [("max_position_deviation_m", "max position deviation (m)",
               "(a) position deviation from the reference solution")]
    if with_voltage:
        panels.append(("max_u_deviation_V", "max voltage deviation (V)",
                       "(b) voltage deviation from the reference solution"))
    figure = new_figure(7.0 * len(panels), 5.5)
    for axes, (quantity, ylabel, title) in zip(np.atleast_1d(figure.subplots(1, len(panels))), panels):
        for label, group in groups.items():
            fit = _fit_of(fits, label, quantity)
            _series(axes, group, quantity, f"{label}: " + (f"slope {fit.slope:.2f}" if fit else "no fit"),
                    styles[label])
            if fit is not None:
                h = np.geomspace(fit.h_min, fit.h_max, 50)
                axes.plot(h, fit.deviation(h), "--", color=styles[label]["color"], linewidth=3, alpha=0.5)
        _without_values(axes, rows, quantity)
        axes.set(xscale="log", yscale="log", xlabel="communication step h (s)", ylabel=ylabel, title=title)
        if any(row["diverged"] for row in rows):
            _headroom(axes, len(groups))
        axes.plot([], [], "--", color="0.3", linewidth=3, alpha=0.5, label="fitted line (asymptotic range)")
        axes.grid(True, which="both", alpha=0.3)
        _legend_of_marks(axes, any(row["diverged"] for row in rows),
                         any(not row["stable"] and not row["diverged"] for row in rows))
    figure.savefig(path, dpi=120)
    return Path(path)


def plot_tracking_and_cost(rows: Sequence[Mapping], path: Path | str) -> Path:
    """Plot the tracking error and the cost of each run against the communication step.

    Against h (s, log): (a) the max position tracking error over the last third of the run (m), (b) the
    wall time of the run (s). One line per series; diverged runs as an x at the top edge of (a) and as
    x markers at their wall time in (b).

    Writes and returns ``path`` (its suffix sets the format).
    """
    groups = group_rows(rows)
    styles = _styles(list(groups), groups)
    figure = new_figure(12.0, 5.0)
    tracking, cost = figure.subplots(1, 2, sharex=True)
    for label, group in groups.items():
        style = styles[label]
        _series(tracking, group, "max_position_error_m", label, style)
        steps, wall = _values(group, "wall_time_s")
        converged = np.array([not row["diverged"] for row in group])
        cost.plot(steps[converged], wall[converged], color=style["color"], marker=style["marker"],
                  linestyle=style["linestyle"], label=label)
        cost.plot(steps[~converged], wall[~converged], "x", color=style["color"], markersize=9, markeredgewidth=2)
    _without_values(tracking, rows, "max_position_error_m")
    tracking.set(xscale="log", yscale="log", xlabel="communication step h (s)",
                 ylabel="max position error, last third (m)", title="(a) tracking error over the last third")
    if any(row["diverged"] for row in rows):
        _headroom(tracking, len(groups))
    cost.set(xscale="log", yscale="log", xlabel="communication step h (s)", ylabel="wall time (s)",
             title="(b) cost of the run")
    any_diverged = any(row["diverged"] for row in rows)
    _legend_of_marks(tracking, any_diverged, any(not row["stable"] and not row["diverged"] for row in rows))
    if any_diverged:
        cost.plot([], [], "x", color="0.3", markersize=9, markeredgewidth=2, label="diverged (stopped early)")
    cost.legend(loc="best", fontsize="small")
    for axes in (tracking, cost):
        axes.grid(True, which="both", alpha=0.3)
    figure.savefig(path, dpi=120)
    return Path(path)


def _has(trajectory, key: str) -> bool:
    try:
        trajectory[key]
    except (KeyError, ValueError, IndexError):
        return False
    return True


def plot_paths(trajectories: Mapping[str, Mapping], reference_traj: Mapping, path: Path | str) -> Path:
    """Plot the robot's path in the plane for several runs over the reference solution's path.

    Equal axes, starts marked. The view is the reference paths plus a margin, so a diverging path
    leaves it rather than shrinking it. ``trajectories``: label -> anything indexable by ``"x"`` and ``"y"``
    (m), non-finite points left out; ``reference_traj`` likewise, optionally with the reference robot's
    ``"x_r"`` and ``"y_r"``.

    Writes and returns ``path`` (its suffix sets the format).
    """
    figure = new_figure(7.0, 7.0)
    axes = figure.add_subplot()
    names = [key for key in ("x", "y", "x_r", "y_r") if _has(reference_traj, key)]
    if "x_r" in names and "y_r" in names:
        axes.plot(reference_traj["x_r"], reference_traj["y_r"], ":", color="0.5", linewidth=2, label="reference robot")
    axes.plot(reference_traj["x"], reference_traj["y"], "-", color="black", linewidth=2.5, alpha=0.5,
              label="reference solution (continuous)")
    axes.plot(reference_traj["x"][0], reference_traj["y"][0], "o", color="black", markersize=8, label="start")
    for index, (label, trajectory) in enumerate(trajectories.items()):
        x, y = np.asarray(trajectory["x"], dtype=float), np.asarray(trajectory["y"], dtype=float)
        finite = np.isfinite(x) & np.isfinite(y)
        axes.plot(x[finite], y[finite], "--", color=f"C{index % 10}", label=label)
        if finite.any():
            axes.plot(x[finite][0], y[finite][0], "s", color=f"C{index % 10}", markersize=5)
    xs = np.concatenate([np.ravel(reference_traj[key]) for key in ("x", "x_r") if key in names])
    ys = np.concatenate([np.ravel(reference_traj[key]) for key in ("y", "y_r") if key in names])
    xs, ys = xs[np.isfinite(xs)], ys[np.isfinite(ys)]
    margin = 0.15 * max(np.ptp(xs), np.ptp(ys), 1e-3)
    axes.set_xlim(xs.min() - margin, xs.max() + margin)
    axes.set_ylim(ys.min() - margin, ys.max() + margin)
    axes.set_aspect("equal", adjustable="box")
    axes.set(xlabel="x (m)", ylabel="y (m)", title="Paths in the plane by communication step")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best", fontsize="small")
    figure.savefig(path, dpi=120)
    return Path(path)


def plot_spectral_radius(curves: Mapping[str, tuple[Sequence[float], Sequence[float]]],
                         measured: Mapping[str, float | None], path: Path | str, *,
                         predicted: Mapping[str, float | None] | None = None) -> Path:
    """Plot the predicted spectral radius against the communication step, with the boundaries.

    One curve of rho (1) against h (s, log) per series, the line rho = 1, each measured boundary h* as a
    vertical dashed line in its series' colour and each predicted one as a dotted line. The y axis is
    logarithmic if rho spans more than a factor 20. ``curves``: coupling order or series label -> ``(steps,
    rho)`` (``stability.spectral_radius_curve``); ``measured``, ``predicted``: the same keys -> h* in s, None
    or non-finite drawing no line.

    Writes and returns ``path`` (its suffix sets the format).
    """
    figure = new_figure(7.5, 5.0)
    axes = figure.add_subplot()
    predicted = predicted or {}
    colours = {order: f"C{index % 10}" for index, order in enumerate(dict.fromkeys([*curves, *measured, *predicted]))}
    positive = []
    for order, (steps, rho) in curves.items():
        steps, rho = np.asarray(steps, dtype=float), np.asarray(rho, dtype=float)
        axes.plot(steps, rho, "-", color=colours[order], label=f"{order}: predicted rho")
        positive.append(rho[np.isfinite(rho) & (rho > 0)])
    axes.axhline(1.0, color="black", linewidth=1, label="rho = 1 (stability limit)")
    for order, h in measured.items():
        if h is not None and np.isfinite(h):
            axes.axvline(h, color=colours[order], linestyle="--", label=f"{order}: measured h* = {h:.3g} s")
    for order, h in predicted.items():
        if h is not None and np.isfinite(h):
            axes.axvline(h, color=colours[order], linestyle=":", linewidth=2,
                         label=f"{order}: predicted h* = {h:.3g} s")
    values = np.concatenate(positive) if positive else np.array([1.0])
    if values.size and values.max() / max(values.min(), 1e-300) > 20:
        axes.set_yscale("log")
    axes.set(xscale="log", xlabel="communication step h (s)", ylabel="spectral radius rho (1)",
             title="Predicted spectral radius and measured boundaries")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend(loc="best", fontsize="small")
    figure.savefig(path, dpi=120)
    return Path(path)


def plot_work_precision(rows: Sequence[Mapping], path: Path | str) -> Path:
    """Plot the work-precision diagram of a sweep.

    The largest position deviation from the reference solution (m) against the wall time (s) and
    against the FMUs' doStep calls; one line per fixed-step series (its step sizes) and one marked line
    per error-controlled series (its tolerances in m, annotated). Runs that diverged or have no
    deviation are left out.

    Writes and returns ``path`` (its suffix sets the format).
    """
    figure = new_figure(12.0, 5.0)
    panels = figure.subplots(1, 2, sharey=True)
    groups = group_rows([row for row in rows if np.isfinite(_number(row.get("max_position_deviation_m")))])
    plotted = set()
    for index, (label, group) in enumerate(groups.items()):
        controlled = group[0].get("tolerance") is not None
        if controlled:
            group = sorted(group, key=lambda row: -row["tolerance"])
        for panel, (axes, key) in enumerate(zip(panels, ("wall_time_s", "fmu_steps"))):
            points = [(_number(row.get(key)), _number(row["max_position_deviation_m"]), row) for row in group]
            points = [(x, y, row) for x, y, row in points if x > 0 and y > 0]  # NaN compares False
            if not points:
                continue
            plotted.add(panel)
            axes.plot([x for x, _, _ in points], [y for _, y, _ in points], "s--" if controlled else "o-",
                      color=f"C{index % 10}", label=label, markersize=5 if controlled else 3)
            for x, y, row in points if controlled else ():
                axes.annotate(f"{row['tolerance']:g} m", (x, y), textcoords="offset points", xytext=(4, 4),
                              fontsize="x-small")
    for panel, (axes, xlabel) in enumerate(zip(panels, ("wall time (s)", "doStep calls, all FMUs"))):
        axes.set(xlabel=xlabel)
        if panel in plotted:
            axes.set(xscale="log", yscale="log")
        else:
            axes.text(0.5, 0.5, "no runs with this measure", transform=axes.transAxes, ha="center")
        axes.grid(True, which="both", alpha=0.3)
    panels[0].set(ylabel="max position deviation from the reference solution (m)",
                  title="Accuracy against wall time")
    panels[1].set(title="Accuracy against FMU calls")
    if plotted:
        panels[max(plotted)].legend(loc="best", fontsize="small")
    figure.savefig(path, dpi=120)
    return Path(path)


def _number(value) -> float:
    return float("nan") if value is None else float(value)
