"""The figures hold the result: each curve is a column of it against its abscissa, under the label and
units the paper's figures give, in a legend; the file written is a PNG; pyplot's figure list is untouched."""

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

from dsc_fmu.cosim import signals
from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.plots import plot_signals, plot_step_sizes, plot_trajectory
from dsc_fmu.scenario import load_scenario

PNG = b"\x89PNG\r\n\x1a\n"
# Fig. 2's panels: title -> (y label, {curve label: column}).
PANELS = {
    "(a) tracking errors": ("error (m, rad)", {"xe (m)": "xe", "ye (m)": "ye", "thetae (rad)": "thetae"}),
    "(b) control voltages": ("voltage (V)", {"u1 (V)": "u1", "u2 (V)": "u2"}),
    "(c) estimates of a1 = 1/r and a2 = R/r": ("estimate", {"a1_hat (1/m)": "a1_hat", "a2_hat (1)": "a2_hat"}),
    "(d) norms of the parameter estimates": ("norm (1)", {"||W1_hat||": "W1_hat_norm", "||W2_hat||": "W2_hat_norm"}),
}


@pytest.fixture(scope="module")
def synthetic():
    """A robot spiralling onto a reference circle, with a distinct made-up curve per signal."""
    result = np.zeros(301, dtype=signals.DTYPE)
    t = np.linspace(0.0, 3.0, 301)
    result["time"] = t
    result["x_r"], result["y_r"] = 2.0 + 5.0 * np.sin(0.2 * t), 2.0 + 5.0 * (1 - np.cos(0.2 * t))
    result["x"], result["y"] = result["x_r"] + 0.5 * np.exp(-t), result["y_r"] - np.exp(-t)
    for power, name in enumerate(("u1", "u2", "a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm"), start=1):
        result[name] = np.linspace(0.0, 1.0, 301) ** power
    signals.add_tracking_errors(result)
    return result


@pytest.fixture()
def saved(monkeypatch):
    """The figures the plot functions save, in order, each saved as before."""
    figures, save = [], Figure.savefig

    def record(figure, *args, **kwargs):
        figures.append(figure)
        return save(figure, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", record)
    return figures


def curves(axes) -> dict:
    """The axes' lines by label: their (x, y) data."""
    return {line.get_label(): (line.get_xdata(), line.get_ydata()) for line in axes.get_lines()}


def legend(axes) -> list[str]:
    return [text.get_text() for text in axes.get_legend().get_texts()]


def written(path) -> bool:
    return path.read_bytes()[:8] == PNG


def check_trajectory(result, figure):
    (axes,) = figure.axes
    drawn = curves(axes)
    for label, start, (x, y) in (("reference robot", "reference start", ("x_r", "y_r")), ("robot", "robot start", ("x", "y"))):
        np.testing.assert_array_equal(drawn[label][0], result[x])
        np.testing.assert_array_equal(drawn[label][1], result[y])
        np.testing.assert_array_equal(np.ravel(drawn[start]), [result[x][0], result[y][0]])
    assert (axes.get_xlabel(), axes.get_ylabel()) == ("x (m)", "y (m)")
    assert legend(axes) == ["reference robot", "robot", "reference start", "robot start"]


def check_signals(result, figure):
    assert [axes.get_title() for axes in figure.axes] == list(PANELS)
    for axes, (ylabel, columns) in zip(figure.axes, PANELS.values()):
        drawn = curves(axes)
        assert list(drawn) == legend(axes) == list(columns)
        for label, column in columns.items():
            np.testing.assert_array_equal(drawn[label][0], result["time"])
            np.testing.assert_array_equal(drawn[label][1], result[column])
        assert axes.get_ylabel() == ylabel
    assert [axes.get_xlabel() for axes in figure.axes] == ["", "", "time (s)", "time (s)"]


def test_the_trajectory_draws_both_paths_and_their_starts(synthetic, saved, tmp_path):
    figures = plt.get_fignums()
    assert written(plot_trajectory(synthetic, tmp_path / "trajectory.png"))
    check_trajectory(synthetic, *saved)
    assert plt.get_fignums() == figures  # nothing left open in pyplot


def test_the_signals_draw_each_column_against_time(synthetic, saved, tmp_path):
    figures = plt.get_fignums()
    assert written(plot_signals(synthetic, tmp_path / "signals.png"))
    check_signals(synthetic, *saved)
    assert plt.get_fignums() == figures


def test_the_step_sizes_draw_each_step_and_the_positive_errors_under_the_tolerance(saved, tmp_path):
    step_sizes = np.zeros(4, dtype=[("time", float), ("step_size", float), ("estimated_error", float)])
    step_sizes["time"], step_sizes["step_size"] = [0.0, 0.01, 0.03, 0.07], [0.01, 0.02, 0.04, 0.02]
    step_sizes["estimated_error"] = [0.0, 2e-5, 8e-5, 3e-5]  # the first step has no estimate
    assert written(plot_step_sizes(step_sizes, 5e-5, tmp_path / "steps.png"))
    sizes, errors = saved[0].axes
    ((time, size),) = curves(sizes).values()
    np.testing.assert_array_equal(time, step_sizes["time"])
    np.testing.assert_array_equal(size, step_sizes["step_size"])
    assert sizes.get_ylabel() == "step size (s)" and "tolerance 5e-05 m" in sizes.get_title()
    drawn = curves(errors)
    np.testing.assert_array_equal(drawn["estimated error of the step"][0], [0.01, 0.03, 0.07])
    np.testing.assert_array_equal(drawn["estimated error of the step"][1], [2e-5, 8e-5, 3e-5])
    np.testing.assert_array_equal(drawn["tolerance"][1], [5e-5, 5e-5])
    assert (errors.get_xlabel(), errors.get_ylabel()) == ("time (s)", "error (m)")
    assert legend(errors) == ["estimated error of the step", "tolerance"]
    assert sizes.get_yscale() == errors.get_yscale() == "log"


def test_plots_of_a_cosimulation(fmu_paths, saved, tmp_path):
    result = cosimulate(load_scenario("paper"), fmu_paths, step_size=0.01, stop_time=1.0).result
    assert written(plot_trajectory(result, tmp_path / "trajectory.png"))
    assert written(plot_signals(result, tmp_path / "signals.png"))
    check_trajectory(result, saved[0])
    check_signals(result, saved[1])
