"""The paper's figures from a result: Fig. 1 (paths in the plane) and Fig. 2 (errors, voltages, estimates)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["plot_trajectory", "plot_signals"]


def new_figure(width: float, height: float) -> Figure:
    """A figure (inches, constrained layout) on an Agg canvas, outside pyplot: no display, no global state."""
    figure = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def plot_trajectory(result: np.ndarray, path: Path | str) -> Path:
    """Fig. 1: the reference path (x_r, y_r) and the robot's path (x, y) in the plane (m).

    Parameters
    ----------
    result : numpy.ndarray
        Rows of dtype ``signals.DTYPE``.
    path : pathlib.Path or str
        The image to write (format from its suffix).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    figure = new_figure(6.0, 6.0)
    axes = figure.add_subplot()
    axes.plot(result["x_r"], result["y_r"], "--", color="tab:blue", label="reference robot")
    axes.plot(result["x"], result["y"], "-", color="tab:red", label="robot")
    axes.plot(result["x_r"][0], result["y_r"][0], "o", color="tab:blue", label="reference start")
    axes.plot(result["x"][0], result["y"][0], "s", color="tab:red", label="robot start")
    axes.set_aspect("equal", adjustable="datalim")
    axes.set(xlabel="x (m)", ylabel="y (m)", title="Paths in the plane")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best")
    figure.savefig(path, dpi=120)
    return Path(path)


def plot_signals(result: np.ndarray, path: Path | str) -> Path:
    """Fig. 2 against time (s): tracking errors, voltages, estimates and the weights' norms.

    Panels: (a) xe, ye (m) and thetae (rad); (b) u1, u2 (V); (c) a1_hat (1/m) and a2_hat (1); (d) the
    norms of W1_hat and W2_hat (1).

    Parameters
    ----------
    result : numpy.ndarray
        Rows of dtype ``signals.DTYPE``.
    path : pathlib.Path or str
        The image to write (format from its suffix).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    time = result["time"]
    figure = new_figure(10.0, 7.5)
    (errors, voltages), (estimates, norms) = figure.subplots(2, 2, sharex=True)
    panels = (
        (errors, "(a) tracking errors", "error (m, rad)",
         (("xe", "-", "xe (m)"), ("ye", "--", "ye (m)"), ("thetae", ":", "thetae (rad)"))),
        (voltages, "(b) control voltages", "voltage (V)", (("u1", "-", "u1 (V)"), ("u2", "--", "u2 (V)"))),
        (estimates, "(c) estimates of a1 = 1/r and a2 = R/r", "estimate",
         (("a1_hat", "-", "a1_hat (1/m)"), ("a2_hat", ":", "a2_hat (1)"))),
        (norms, "(d) norms of the parameter estimates", "norm (1)",
         (("W1_hat_norm", "-", "||W1_hat||"), ("W2_hat_norm", ":", "||W2_hat||"))),
    )
    for axes, title, ylabel, curves in panels:
        for column, style, label in curves:
            axes.plot(time, result[column], style, label=label)
        axes.set(title=title, ylabel=ylabel)
        axes.grid(True, alpha=0.3)
        axes.legend(loc="best")
    for axes in (estimates, norms):
        axes.set_xlabel("time (s)")
    figure.savefig(path, dpi=120)
    return Path(path)


def plot_step_sizes(step_sizes: np.ndarray, tolerance: float, path: Path | str) -> Path:
    """An error-controlled run's step size (s) and estimated error per step (m) against time, ``tolerance`` (m)
    marked, written to ``path``."""
    figure = new_figure(8.0, 5.5)
    sizes, errors = figure.subplots(2, 1, sharex=True)
    sizes.semilogy(step_sizes["time"], step_sizes["step_size"], ".-", markersize=2, color="tab:blue")
    sizes.set(ylabel="step size (s)", title=f"Error-controlled communication step, tolerance {tolerance:g} m")
    positive = step_sizes["estimated_error"] > 0
    errors.semilogy(step_sizes["time"][positive], step_sizes["estimated_error"][positive], ".", markersize=2,
                    color="tab:red", label="estimated error of the step")
    errors.axhline(tolerance, color="black", linestyle="--", label="tolerance")
    errors.set(xlabel="time (s)", ylabel="error (m)")
    errors.legend(loc="best")
    for axes in (sizes, errors):
        axes.grid(True, which="both", alpha=0.3)
    figure.savefig(path, dpi=120)
    return Path(path)
