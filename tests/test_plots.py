"""The figures: written as PNG files of the expected size, without touching pyplot's figure list."""

import matplotlib.image
import matplotlib.pyplot as plt
import numpy as np
import pytest

from dsc_fmu.cosim import signals
from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.plots import plot_signals, plot_trajectory
from dsc_fmu.scenario import load_scenario

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def synthetic():
    """A robot spiralling onto a reference circle, with smooth made-up signals."""
    result = np.zeros(301, dtype=signals.DTYPE)
    t = np.linspace(0.0, 3.0, 301)
    result["time"] = t
    result["x_r"], result["y_r"] = 2.0 + 5.0 * np.sin(0.2 * t), 2.0 + 5.0 * (1 - np.cos(0.2 * t))
    result["x"], result["y"] = result["x_r"] + 0.5 * np.exp(-t), result["y_r"] - np.exp(-t)
    for name in ("u1", "u2", "a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm"):
        result[name] = np.linspace(0.0, 1.0, 301)
    signals.add_tracking_errors(result)
    return result


@pytest.mark.parametrize("plot", [plot_trajectory, plot_signals])
def test_plots_write_png(synthetic, tmp_path, plot):
    figures = plt.get_fignums()
    path = plot(synthetic, tmp_path / "figure.png")
    assert path.read_bytes()[:8] == PNG
    image = matplotlib.image.imread(path)
    assert len(np.unique(image.reshape(-1, image.shape[2]), axis=0)) > 10  # lines, text: not a blank canvas
    assert plt.get_fignums() == figures  # nothing left open in pyplot


def test_plots_of_a_cosimulation(fmu_paths, tmp_path):
    run = cosimulate(load_scenario("paper"), fmu_paths, step_size=0.01, stop_time=1.0)
    for plot in (plot_trajectory, plot_signals):
        path = plot(run.result, tmp_path / f"{plot.__name__}.png")
        assert path.stat().st_size > 10_000 and path.read_bytes()[:8] == PNG
