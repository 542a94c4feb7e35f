"""The paper's scenario end to end: its acceptance figures, and co-simulation converging to the
reference solution at first order in the communication step (the zero-order hold)."""

import numpy as np
import pytest

from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.metrics import tracking_metrics
from dsc_fmu.cosim.reference_solution import reference_solution
from dsc_fmu.scenario import load_scenario, scenario_names

pytestmark = pytest.mark.slow

PAPER = load_scenario("paper")


@pytest.fixture(scope="module")
def reference():
    return reference_solution(PAPER)


@pytest.fixture(scope="module")
def runs(fmu_paths):
    return {h: cosimulate(PAPER, fmu_paths, step_size=h).result for h in (1e-3, 2e-4)}


def deviation(result, reference):
    np.testing.assert_allclose(result["time"], reference["time"], rtol=0, atol=1e-9)
    return np.hypot(result["x"] - reference["x"], result["y"] - reference["y"]).max()


def test_paper_scenario_tracks_within_the_acceptance_bounds(runs):
    result = runs[1e-3]
    late = (result["time"] >= 20.0) & (result["time"] <= 30.0)
    assert result["time"][-1] == 30.0
    assert result["position_error"][late].max() <= 0.05
    assert np.abs(result["thetae"][late]).max() <= 0.015


def test_cosimulation_converges_to_the_reference_solution_at_first_order(runs, reference):
    coarse, fine = deviation(runs[1e-3], reference), deviation(runs[2e-4], reference)
    assert coarse <= 0.02
    assert fine <= 0.005
    assert 5 * 0.7 < coarse / fine < 5 * 1.3


@pytest.mark.parametrize("order", ["gauss-seidel", "jacobi"])
def test_both_coupling_orders_stay_near_the_reference_solution(fmu_paths, reference, order):
    result = cosimulate(PAPER, fmu_paths, step_size=1e-3, order=order, stop_time=10.0).result
    assert deviation(result, reference[: len(result)]) <= 0.02


@pytest.mark.parametrize("name", scenario_names())
def test_every_scenario_runs_and_agrees_with_its_reference_solution(fmu_paths, name):
    scenario = load_scenario(name)
    result = cosimulate(scenario, fmu_paths).result
    assert np.isfinite(result.view((float, len(result.dtype)))).all()
    assert deviation(result, reference_solution(scenario)) <= 0.1
    metrics = tracking_metrics(result, scenario.simulation.stop_time)
    assert metrics["max_position_error_m"] < 0.5


def test_the_ahead_start_exercises_the_beta_guard(fmu_paths):
    scenario = load_scenario("ahead_start").with_simulation(stop_time=2.0)
    result = cosimulate(scenario, fmu_paths).result
    assert result["beta"][0] < scenario.controller["beta_min"]
    assert result["beta_guard_count"][-1] > 0
    assert np.all(np.diff(result["beta_guard_count"]) >= 0)


@pytest.mark.parametrize("order", ["gauss-seidel", "jacobi"])
def test_linear_coupling_converges_at_second_order(fmu_paths, reference, order):
    """With ``coupling = "linear"`` the deviation from the reference solution falls with h^2 (observed
    order >= 1.8 between 2 ms and 1 ms) and is at most 2 mm at 1 ms over the paper's 30 s."""
    coarse, fine = (deviation(cosimulate(PAPER, fmu_paths, step_size=h, order=order, coupling="linear").result,
                              reference) for h in (2e-3, 1e-3))
    assert fine <= 2e-3
    assert np.log2(coarse / fine) >= 1.8
