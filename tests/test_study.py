"""Sweep analysis on synthetic data with known answers: fitted order, stability bracket and its
refinement, and the JSON summary."""

import json
import math

import numpy as np
import pytest

from dsc_fmu.study.analysis import (Boundary, OrderFit, fit_order, fit_orders, grid_bracket, grid_brackets, group_label,
                           refine_boundary, summarise, to_json, write_summary_json)

STEPS = np.geomspace(1e-4, 5e-2, 19)
BOUNDARIES = {"gauss-seidel": 0.0123, "jacobi": 0.0061}  # s: stable iff h < boundary
KNEE = 3e-3  # s
DEFINITION = "not diverged and max position error over the last third below 0.1 m"


def synthetic_rows(steps=STEPS, boundaries=BOUNDARIES, discretizations=("rk4", "euler")):
    """Rows of a made-up sweep: deviation 0.5 h (1 + (h/KNEE)^3) (first order, knee at KNEE),
    diverged at and above each order's boundary (deviations NaN, tracking error None)."""
    rows = []
    for order, boundary in boundaries.items():
        for discretization in discretizations:
            for h in steps:
                diverged = bool(h >= boundary)
                deviation = math.nan if diverged else 0.5 * h * (1 + (h / KNEE) ** 3)
                rows.append({
                    "scenario": "paper", "step_size": float(h), "order": order, "discretization": discretization,
                    "sample": None, "key": f"{order}-{discretization}-{h:.3g}", "diverged": diverged,
                    "diverged_time": 3.21 if diverged else None, "diverged_signal": "u1" if diverged else None,
                    "stable": not diverged, "max_position_deviation_m": deviation,
                    "rms_position_deviation_m": deviation / 3, "max_heading_deviation_rad": 2 * deviation,
                    "rms_heading_deviation_rad": deviation, "max_u_deviation_V": 40 * deviation,
                    "rms_u_deviation_V": 10 * deviation, "final_position_error_m": 0.01,
                    "rms_position_error_m": 0.012, "max_position_error_m": None if diverged else 0.02 + h,
                    "max_abs_thetae_rad": 0.01, "settling_time_0p1_s": None if diverged else 4.5,
                    "max_abs_u_V": 12.0, "beta_guard_count": 0, "wall_time_s": 0.3 / h ** 0.9,
                    "steps": int(round(30 / h)),
                })
    return rows


@pytest.mark.parametrize("p", [1, 2])
def test_exact_power_law_gives_its_order_over_the_whole_range(p):
    fit = fit_order(STEPS, 0.7 * STEPS**p)
    assert fit.slope == pytest.approx(p, abs=1e-9)
    assert 10**fit.intercept == pytest.approx(0.7, rel=1e-9)
    assert (fit.h_min, fit.h_max, fit.points) == (pytest.approx(STEPS[0]), pytest.approx(STEPS[-1]), len(STEPS))
    assert fit.max_residual < 1e-12 and fit.r2 == pytest.approx(1.0)
    np.testing.assert_allclose(fit.deviation(STEPS), 0.7 * STEPS**p, rtol=1e-9)


@pytest.mark.parametrize("noise", [0.0, 0.01])
@pytest.mark.parametrize("knee", [3e-3, 1e-2])
@pytest.mark.parametrize("p", [1, 2])
def test_the_fit_stops_at_the_knee(p, knee, noise):
    factor = 1 + noise * np.random.default_rng(20240501).standard_normal(len(STEPS))
    fit = fit_order(STEPS, 0.7 * STEPS**p * (1 + (STEPS / knee) ** 3) * factor)
    assert fit.slope == pytest.approx(p, abs=0.05)
    assert fit.h_min == pytest.approx(STEPS[0])
    assert fit.h_max <= knee
    assert fit.points >= 3


def test_diverged_and_non_positive_deviations_are_left_out():
    deviations = list(0.5 * STEPS[:10]) + [math.nan, None, 0.0, -1.0, math.inf] + [math.nan] * 4
    fit = fit_order(STEPS, deviations)
    assert fit.slope == pytest.approx(1.0, abs=1e-9)
    assert (fit.points, fit.h_max) == (10, pytest.approx(STEPS[9]))


def test_the_range_starts_above_an_outlier_at_the_smallest_step():
    deviations = 0.5 * STEPS.copy()
    deviations[0] *= 3
    fit = fit_order(STEPS[::-1], deviations[::-1])  # order of the input does not matter
    assert fit.slope == pytest.approx(1.0, abs=1e-9)
    assert fit.h_min == pytest.approx(STEPS[1]) and fit.points == len(STEPS) - 1


@pytest.mark.parametrize("steps, deviations, match", [
    ([1e-3, 2e-3], [1e-3, 2e-3], "2 usable points"),
    ([1e-3, 2e-3, 4e-3, 8e-3], [1e-3, math.nan, None, 8e-3], "2 usable points"),
    ([1e-3, 1e-3, 4e-3], [1e-3, 1.1e-3, 4e-3], "distinct"),
    ([1e-3, 2e-3, 4e-3], [1e-3, 2e-3], "equal length"),
    ([1e-3, 2e-3, 4e-3, 8e-3], [1e-3, 1e-1, 1e-3, 1e-1], "no 3 consecutive"),
])
def test_too_few_or_bad_points_are_a_clear_error(steps, deviations, match):
    with pytest.raises(ValueError, match=match):
        fit_order(steps, deviations)


@pytest.mark.parametrize("steps, flags, bracket", [
    ([1e-3, 2e-3, 5e-3, 1e-2], [True, True, False, False], (2e-3, 5e-3)),
    ([1e-2, 1e-3, 5e-3, 2e-3], [False, True, False, True], (2e-3, 5e-3)),  # unsorted input
    ([1e-3, 2e-3, 5e-3, 1e-2, 2e-2], [True, False, True, True, False], (1e-3, 2e-3)),  # not monotone: first loss
    ([1e-3, 2e-3, 2e-3, 5e-3], [True, True, False, True], (1e-3, 2e-3)),  # one unstable sample makes 2e-3 unstable
    ([1e-3, 2e-3, 5e-3], [True, True, True], None),  # all stable
    ([1e-3, 2e-3, 5e-3], [False, False, False], None),  # none stable
    ([1e-3, 2e-3, 5e-3], [False, True, True], None),  # nothing stable below the first unstable step
])
def test_grid_bracket_is_around_the_first_unstable_step(steps, flags, bracket):
    assert grid_bracket(steps, flags) == bracket


def test_grid_bracket_needs_one_flag_per_step():
    with pytest.raises(ValueError, match="3 step sizes but 2"):
        grid_bracket([1e-3, 2e-3, 5e-3], [True, False])


@pytest.mark.parametrize("bracket", [(0.01, 0.02), (0.005, 0.05), (0.0122, 0.0124), (1e-4, 0.0123)])
@pytest.mark.parametrize("rel_tol", [0.02, 0.005])
def test_refinement_finds_a_known_threshold(bracket, rel_tol):
    threshold, calls = 0.0123, []

    def is_stable(h):
        calls.append(h)
        return h < threshold

    boundary = refine_boundary(is_stable, *bracket, rel_tol=rel_tol)
    assert boundary.h_stable < threshold <= boundary.h_unstable
    assert boundary.relative_width <= rel_tol
    assert boundary.estimate == boundary.h_stable == pytest.approx(threshold, rel=rel_tol)
    expected = max(0, math.ceil(math.log2(math.log(bracket[1] / bracket[0]) / math.log1p(rel_tol))))
    assert len(calls) == len(boundary.evaluated) == expected
    assert [h for h, _ in boundary.evaluated] == calls
    assert all(stable == (h < threshold) for h, stable in boundary.evaluated)
    assert all(bracket[0] < h < bracket[1] for h in calls)


def test_refinement_of_a_non_monotone_stability_ends_at_one_transition():
    def is_stable(h):  # unstable between 0.004 and 0.006, stable again up to 0.009
        return h < 0.004 or 0.006 <= h < 0.009

    boundary = refine_boundary(is_stable, 0.001, 0.02)
    assert is_stable(boundary.h_stable) and not is_stable(boundary.h_unstable)
    assert boundary.relative_width <= 0.02


@pytest.mark.parametrize("bracket, rel_tol", [((0.02, 0.01), 0.02), ((0.0, 0.01), 0.02), ((0.01, 0.02), 0.0)])
def test_refinement_rejects_a_bad_bracket(bracket, rel_tol):
    with pytest.raises(ValueError, match="not allowed"):
        refine_boundary(lambda h: True, *bracket, rel_tol=rel_tol)


def test_group_labels_name_order_discretization_overrides_and_sample():
    row = {"order": "jacobi", "discretization": "euler", "sample": 3, "controller.k4": 2.0, "step_size": 1e-3}
    assert group_label(row) == "jacobi/euler controller.k4=2 sample 3"
    assert group_label({"order": "gauss-seidel", "discretization": "rk4", "sample": None}) == "gauss-seidel/rk4"


def test_fits_and_brackets_by_group():
    rows = synthetic_rows()
    fits, brackets = fit_orders(rows), grid_brackets(rows)
    assert list(fits) == ["gauss-seidel/rk4", "gauss-seidel/euler", "jacobi/rk4", "jacobi/euler"]
    for label, fit in fits.items():
        assert fit["max_position_deviation_m"].slope == pytest.approx(1.0, abs=0.05)
        assert fit["max_u_deviation_V"].slope == pytest.approx(1.0, abs=0.05)
        h_stable, h_unstable = brackets[label]
        assert h_stable < BOUNDARIES[label.split("/")[0]] <= h_unstable
        assert np.flatnonzero(STEPS == h_unstable)[0] == np.flatnonzero(STEPS == h_stable)[0] + 1


def summary_of(rows, predictions, notes=()):
    """The summary of a sweep of ``synthetic_rows``, each nominal bracket refined against BOUNDARIES."""
    boundaries = {label: refine_boundary(lambda h, b=BOUNDARIES[label.split("/")[0]]: h < b, *bracket)
                  for label, bracket in grid_brackets(rows).items() if bracket and " " not in label}
    return summarise(rows, stability_definition=DEFINITION, boundaries=boundaries, predictions=predictions,
                     settings={"scenario": "paper", "step_sizes_s": STEPS, "orders": ("gauss-seidel", "jacobi")},
                     notes=notes)


def test_summary_is_strict_json_with_orders_boundaries_and_ratios(tmp_path):
    rows = synthetic_rows()
    summary = summary_of(rows, {"gauss-seidel": 0.0125, "jacobi": 0.0092}, notes=["Jacobi: delay neglected"])
    assert json.loads(json.dumps(summary, allow_nan=False)) == summary
    assert summary["scenario"] == "paper" and summary["stability_definition"] == DEFINITION
    diverged = sum(row["diverged"] for row in rows)
    assert summary["counts"] == {"runs": len(rows), "diverged": diverged, "unstable": diverged}
    for label, group in summary["groups"].items():
        order = group["order"]
        assert group["runs"] == len(STEPS) and group["diverged"] == int(np.sum(STEPS >= BOUNDARIES[order]))
        assert group["observed_order"]["max_position_deviation_m"]["slope"] == pytest.approx(1.0, abs=0.05)
        stability = group["stability_boundary"]
        assert stability["status"] == "refined"
        assert stability["estimate_s"] == pytest.approx(BOUNDARIES[order], rel=0.02)
        first = stability["refined"]["evaluated"][0]["step_size"]
        assert first == pytest.approx(math.sqrt(np.prod(stability["grid_bracket_s"])))  # geometric midpoint
        ratio = group["prediction"]["ratio_predicted_to_measured"]
        assert ratio == pytest.approx(group["prediction"]["predicted_boundary_s"] / stability["estimate_s"])
        assert group["prediction"]["agrees"] is (order == "gauss-seidel")
    assert summary["notes"] == ["Jacobi: delay neglected"]
    path = write_summary_json(tmp_path / "out", summary)
    assert path.name == "sweep.json" and json.loads(path.read_text()) == summary


def test_summary_without_boundary_in_the_grid_says_so():
    rows = synthetic_rows(boundaries={"gauss-seidel": 1.0, "jacobi": 1e-5}, discretizations=("rk4",))
    summary = summarise(rows, stability_definition=DEFINITION, predictions={"gauss-seidel": 0.01, "jacobi": 1e-5})
    everything, nothing = summary["groups"]["gauss-seidel/rk4"], summary["groups"]["jacobi/rk4"]
    assert everything["stability_boundary"]["status"] == "all stable"
    assert "no boundary within the grid" in everything["stability_boundary"]["message"]
    assert everything["prediction"]["agrees"] is False  # predicted 0.01 s, yet stable up to 0.05 s
    assert nothing["stability_boundary"]["status"] == "none stable"
    assert nothing["prediction"]["agrees"] is True
    assert "error" in nothing["observed_order"]["max_position_deviation_m"]  # every run diverged


def test_summary_uses_the_grid_bracket_when_not_refined():
    summary = summarise(synthetic_rows(discretizations=("rk4",)), stability_definition=DEFINITION)
    stability = summary["groups"]["jacobi/rk4"]["stability_boundary"]
    assert stability["status"] == "grid" and stability["refined"] is None
    assert stability["estimate_s"] == stability["grid_bracket_s"][0]
    assert summary["groups"]["jacobi/rk4"]["prediction"]["agrees"] is None


def test_to_json_converts_numpy_and_non_finite_values():
    value = {"a": np.float64(math.nan), "b": (np.int64(3), np.inf), "c": np.array([1.5, 2.0]), "d": np.bool_(True),
             "e": OrderFit(1, 0, 1e-3, 1e-2, 3, 0, 1).slope, "f": Boundary(1e-3, 2e-3).relative_width}
    assert to_json(value) == {"a": None, "b": [3, None], "c": [1.5, 2.0], "d": True, "e": 1, "f": 1.0}
