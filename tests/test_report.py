"""Sweep figures and report on synthetic rows: PNGs that are not blank, and a report.md that holds
the runs, the fitted orders, the boundaries, the figures and the >20 % note."""

import math
import re

import matplotlib.image
import matplotlib.pyplot as plt
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
import numpy as np
import pytest

from dsc_fmu.study.report import write_report
from dsc_fmu.study.analysis import fit_orders, group_rows, summarise
from dsc_fmu.study.figures import (
    plot_deviation, plot_paths, plot_spectral_radius, plot_tracking_and_cost, plot_work_precision,
)
from test_study import BOUNDARIES, KNEE, STEPS, summary_of, synthetic_rows

PNG = b"\x89PNG\r\n\x1a\n"
REASON = "the linearisation neglects the saturation of u"


@pytest.fixture(scope="module")
def rows():
    """The synthetic sweep and a series with an override: stable at 1 ms, not stable (but not
    diverged, tracking error NaN) at 2 ms."""
    extra = [{**row, "controller.k4": 5.0, "key": row["key"] + "-k4"} for row in synthetic_rows()[4:6]]
    extra[1].update(stable=False, max_position_error_m=math.nan)
    return synthetic_rows() + extra


def circle(t, radius, phase=0.0):
    return {"time": t, "x": radius * np.sin(0.2 * t + phase), "y": radius * (1 - np.cos(0.2 * t + phase)),
            "x_r": 5 * np.sin(0.2 * t), "y_r": 5 * (1 - np.cos(0.2 * t))}


def figures(rows, out):
    t = np.linspace(0, 30, 601)
    diverging = circle(t, 5.3)
    diverging["x"] = diverging["x"] * np.exp(t / 5)
    diverging["x"][-50:] = np.nan
    return {
        "deviation": plot_deviation(rows, fit_orders(rows), out / "deviation.png"),
        "tracking_and_cost": plot_tracking_and_cost(rows, out / "tracking_and_cost.png"),
        "paths": plot_paths({"h = 0.001 s": circle(t, 5.05), "h = 0.01 s (diverged)": diverging},
                            circle(t, 5.0), out / "paths.png"),
        "spectral_radius": plot_spectral_radius(
            {order: (STEPS, 0.99 + (STEPS / h) ** 2) for order, h in BOUNDARIES.items()},
            {"gauss-seidel": 0.012, "jacobi": None}, out / "spectral_radius.png",
            predicted={"gauss-seidel": 0.0125, "jacobi": 0.0092}),
        "work_precision": plot_work_precision(rows, out / "work_precision.png"),
    }


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    return tmp_path_factory.mktemp("sweep")


@pytest.fixture(scope="module")
def figure_paths(rows, out):
    open_figures = plt.get_fignums()
    paths = figures(rows, out)
    assert plt.get_fignums() == open_figures  # nothing left open in pyplot
    return paths


def test_plots_write_png_files_that_are_not_blank(figure_paths):
    for name, path in figure_paths.items():
        assert path.read_bytes()[:8] == PNG, name
        pixels = (matplotlib.image.imread(path)[..., :3] * 255).astype(np.uint32)
        colours = pixels[..., 0] << 16 | pixels[..., 1] << 8 | pixels[..., 2]
        assert len(np.unique(colours)) > 50, name  # lines, markers, text: not a blank canvas


def test_deviation_plot_computes_its_fits_if_none_are_given(rows, tmp_path, monkeypatch):
    """Given no fits, the figure fits each series itself: its dashed line is the least-squares line of
    log10 deviation against log10 h (numpy.polyfit) over the series' runs in its range, with that slope in
    the legend; the range starts at the smallest step and stops where the next step would leave the line
    (0.03 in log10), at or below the knee of the first-order data; a series of two runs has no fit."""
    drawn = []
    monkeypatch.setattr(Figure, "savefig", lambda figure, *args, **kwargs: drawn.append(figure))
    plot_deviation(rows, None, tmp_path / "deviation.png", with_voltage=False)
    [axes] = drawn[0].axes
    legend = {text.get_text() for text in axes.get_legend().get_texts()}
    dashed = {to_hex(line.get_color()): line for line in axes.get_lines()
              if line.get_linestyle() == "--" and len(line.get_xdata()) == 50}
    groups = group_rows(rows)
    assert len(dashed) == sum(len(group) >= 3 for group in groups.values()) == 4
    for index, (label, group) in enumerate(groups.items()):
        if len(group) < 3:
            assert f"{label}: no fit" in legend
            continue
        h, d = np.log10(dashed[to_hex(f"C{index}")].get_data())
        steps = np.array([row["step_size"] for row in group])
        deviations = np.array([row["max_position_deviation_m"] for row in group])
        inside = (steps >= 10 ** h[0] * (1 - 1e-12)) & (steps <= 10 ** h[-1] * (1 + 1e-12))
        slope, intercept = np.polyfit(np.log10(steps[inside]), np.log10(deviations[inside]), 1)
        np.testing.assert_allclose(d, intercept + slope * h, rtol=0, atol=1e-12)
        assert f"{label}: slope {slope:.2f}" in legend and abs(slope - 1) < 0.05
        assert 10 ** h[0] == pytest.approx(steps[0]) and 10 ** h[-1] <= KNEE
        wider = inside | (steps == steps[~inside][0])
        x, y = np.log10(steps[wider]), np.log10(deviations[wider])
        assert np.abs(y - np.polyval(np.polyfit(x, y, 1), x)).max() >= 0.03


@pytest.fixture(scope="module")
def report(rows, out, figure_paths):
    summary = summary_of(rows, {"gauss-seidel": 0.0125, "jacobi": 0.0092}, notes=[REASON])
    return out, write_report(out, summary, rows, figure_paths).read_text(), summary


def test_report_names_the_scenario_settings_and_definition(report):
    _, text, summary = report
    assert text.startswith("# Step-size sweep of the scenario `paper`")
    assert "- orders: gauss-seidel, jacobi" in text
    assert "- step_sizes_s: 0.0001, 0.000141, " in text
    assert summary["stability_definition"] in text


def test_report_has_one_table_row_per_run(report, rows):
    _, text, _ = report
    runs = text.split("## Runs")[1]
    assert len([line for line in runs.splitlines() if line.startswith("| ")]) == len(rows) + 1
    h = STEPS[0]
    deviation = 0.5 * h * (1 + (h / 3e-3) ** 3)
    assert (f"| 0.0001 | gauss-seidel | rk4 | hold | – | nominal | yes | {deviation:.3g} | {deviation / 3:.3g} | "
            f"{2 * deviation:.3g} | {40 * deviation:.3g} | {0.02 + h:.3g} | {0.3 / h ** 0.9:.3g} |") in runs
    assert "| 0.05 | jacobi | euler | hold | – | nominal | diverged at t = 3.21 s (u1) | – | – | – | – | – |" in runs
    assert f"| {STEPS[5]:.3g} | gauss-seidel | rk4 | hold | – | controller.k4 = 5 | no | " in runs


def test_report_gives_the_fitted_order_and_explains_it(report):
    _, text, summary = report
    slope = summary["groups"]["gauss-seidel/rk4"]["observed_order"]["max_position_deviation_m"]["slope"]
    assert f"| gauss-seidel/rk4 | {slope:.3g} | 0.0001 to " in text
    assert "zero-order hold" in text and "O(h)" in text and "first order, as expected" in text


def test_report_gives_boundaries_predictions_and_the_disagreement(report):
    _, text, summary = report
    for label, group in summary["groups"].items():
        if group["overrides"]:
            assert group["prediction"]["predicted_boundary_s"] is None  # the prediction is for nominal parameters
            continue
        stability, prediction = group["stability_boundary"], group["prediction"]
        assert (f"| {label} | {stability['grid_bracket_s'][0]:.3g} to {stability['grid_bracket_s'][1]:.3g} | "
                f"{stability['refined']['h_stable_s']:.3g} to {stability['refined']['h_unstable_s']:.3g} | "
                f"{stability['estimate_s']:.3g} | {len(stability['refined']['evaluated'])} | "
                f"{prediction['predicted_boundary_s']:.3g} | {prediction['ratio_predicted_to_measured']:.3g} |") in text
    assert "differ by more than 20%** for jacobi/rk4, jacobi/euler" in text
    assert f"- {REASON}" in text


def test_report_links_the_figures_it_was_given(report):
    out, text, _ = report
    links = re.findall(r"!\[[^]]+\]\(([^)]+)\)", text)
    assert links == ["deviation.png", "tracking_and_cost.png", "paths.png", "spectral_radius.png", "work_precision.png"]
    assert all((out / link).is_file() for link in links)


def test_report_without_disagreement_or_reason(rows, tmp_path):
    agreeing = summary_of(rows, {"gauss-seidel": 0.0125, "jacobi": 0.0062})
    text = write_report(tmp_path, agreeing, rows, {"paths": tmp_path / "missing.png"}).read_text()
    assert "more than 20%" not in text and "agrees with its measurement within 20%" in text
    assert "figure `missing.png` was not written" in text and "![" not in text
    disagreeing = summary_of(rows, {"gauss-seidel": 0.02, "jacobi": 0.0062})
    text = write_report(tmp_path, disagreeing, rows, {}).read_text()
    assert "differ by more than 20%** for gauss-seidel/rk4, gauss-seidel/euler" in text
    assert "No reason was given" in text


def test_paths_take_structured_arrays_and_npz_files(tmp_path):
    from dsc_fmu.cosim import signals

    t = np.linspace(0, 30, 301)
    reference = np.zeros(len(t), dtype=signals.DTYPE)
    for name, values in circle(t, 5.0).items():
        reference[name] = values
    np.savez(tmp_path / "run.npz", **circle(t, 5.2))
    with np.load(tmp_path / "run.npz") as run:
        path = plot_paths({"h = 0.005 s": run}, reference, tmp_path / "paths.png")
    assert path.stat().st_size > 10_000
    without_reference_robot = {"x": reference["x"], "y": reference["y"]}
    assert plot_paths({}, without_reference_robot, tmp_path / "alone.png").stat().st_size > 5_000


def test_plots_and_report_of_a_sweep_where_every_run_diverged(tmp_path):
    rows = synthetic_rows(steps=STEPS[::4], boundaries={"jacobi": 1e-6}, discretizations=("rk4",))
    assert plot_deviation(rows, None, tmp_path / "deviation.png").stat().st_size > 10_000
    assert plot_tracking_and_cost(rows, tmp_path / "tracking.png").stat().st_size > 10_000
    summary = summarise(rows, stability_definition="not diverged", predictions={"jacobi": 1e-3})
    text = write_report(tmp_path, summary, rows, {}).read_text()
    assert "already unstable at the smallest step 0.0001 s" in text
    assert "jacobi/rk4: no order fitted: 0 usable points" in text
    assert "differ by more than 20%** for jacobi/rk4" in text  # predicted 1 ms, unstable at 0.1 ms


def test_the_order_verdict_expects_two_only_of_the_linear_coupling_with_rk4(tmp_path):
    """Euler is first order itself, so with the linear coupling its series is expected at slope 1; a
    linear RK4 series at slope 1 is called out."""
    rows = []
    for row in synthetic_rows(boundaries={"gauss-seidel": 1.0, "jacobi": 1.0}):
        h = row["step_size"]
        linear = dict(row, coupling="linear", key=row["key"] + "-linear")
        if (row["order"], row["discretization"]) == ("gauss-seidel", "rk4"):
            for name in ("max_position_deviation_m", "max_heading_deviation_rad", "max_u_deviation_V"):
                linear[name] = row[name] * h / (1 + (h / 3e-3) ** 3)  # O(h^2) up to the same knee
        rows += [row, linear]
    summary = summarise(rows, stability_definition="-", boundaries={}, predictions={}, settings={"scenario": "paper"})
    text = write_report(tmp_path, summary, rows, {}).read_text()
    verdicts = dict(re.findall(r"^- (\S+/\S+(?: linear)?): the maximum position deviation falls as .*: (.*)\.$",
                               text, re.MULTILINE))
    assert verdicts == {
        "gauss-seidel/rk4": "first order, as expected", "gauss-seidel/euler": "first order, as expected",
        "jacobi/rk4": "first order, as expected", "jacobi/euler": "first order, as expected",
        "gauss-seidel/rk4 linear": "second order, as expected", "gauss-seidel/euler linear": "first order, as expected",
        "jacobi/rk4 linear": "NOT second order", "jacobi/euler linear": "first order, as expected",
    }
