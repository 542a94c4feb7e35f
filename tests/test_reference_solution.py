"""The monolithic reference solution against the equations, analytic solutions and independent integrations."""

import math

import numpy as np
import pytest

from dsc_fmu.cosim import reference_solution as rs
from dsc_fmu.models.controller import control_law, gains, wrap
from dsc_fmu.models.plant import plant_coefficients, plant_derivatives
from dsc_fmu.models.reference import reference_derivatives, velocity
from dsc_fmu.scenario import load_scenario
from dsc_fmu.cosim.signals import COLUMNS, DTYPE

POSITION = ("x", "y", "theta")


@pytest.fixture(scope="module")
def paper():
    """The paper scenario, 30 s, at the default tolerances."""
    return rs.reference_solution(load_scenario("paper"))


@pytest.fixture(scope="module")
def paper_dense():
    """The first 4 s of the paper scenario on a 1 ms grid."""
    return rs.reference_solution(load_scenario("paper"), times=np.arange(4001) * 1e-3)


def test_columns_and_default_grid(paper):
    """Every column of signals.DTYPE is filled; rows at k * output_interval up to stop_time."""
    assert paper.dtype == DTYPE
    assert len(paper) == 3001
    np.testing.assert_array_equal(paper["time"], np.arange(3001) * 0.01)
    assert paper["time"][-1] == 30.0
    for name in COLUMNS:
        assert np.all(np.isfinite(paper[name])), name


@pytest.mark.parametrize(
    "stop_time, interval, expected_last, expected_len",
    [(0.1, 0.01, 0.1, 11), (0.105, 0.01, 0.105, 12), (0.3, 0.1, 0.3, 4), (1.0, 0.3, 1.0, 5)],
)
def test_output_times(stop_time, interval, expected_last, expected_len):
    times = rs.output_times(stop_time, interval)
    assert len(times) == expected_len
    assert times[-1] == expected_last
    np.testing.assert_array_equal(times[:-1], np.arange(expected_len - 1) * interval)


@pytest.mark.parametrize("name", ["paper", "ahead_start", "figure_eight"])
def test_initial_state(name):
    """docs/model.md §5: plant at rest, estimates zero, x2f = x2bar and x3f = x3bar (both filter derivatives 0)."""
    scenario = load_scenario(name)
    state = rs.initial_closed_loop_state(scenario)
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    p, ref = scenario.plant, scenario.reference
    assert state[rs.PLANT_STATES] == [p["x0"], p["y0"], p["theta0"], 0.0, 0.0, 0.0, 0.0]
    assert state[rs.REFERENCE_STATES] == [ref["x0"], ref["y0"], ref["theta0"]]
    xc = state[rs.CONTROLLER_STATES]
    assert xc[:2] == [0.0, 0.0] and xc[4:12] == [0.0] * 8 and xc[14:20] == [0.0] * 6
    law = control_law(g, xc, rs.measurements(k, ref, 0.0, state[rs.PLANT_STATES], state[rs.REFERENCE_STATES]))
    assert law.derivative[2:4] == [0.0, 0.0]
    assert law.derivative[12:14] == [0.0, 0.0]


@pytest.mark.parametrize("name", ["paper", "ahead_start", "figure_eight"])
@pytest.mark.parametrize("seed", range(3))
def test_closed_loop_derivatives_are_the_three_models(name, seed):
    """The ODE is plant (6)-(8) under u of (26), controller fed m of the current states, reference (9)."""
    scenario = load_scenario(name)
    k, g, ref = plant_coefficients(scenario.plant), gains(scenario.controller), scenario.reference
    rng = np.random.default_rng(seed)
    state = list(rng.uniform(-2, 2, 30))
    t = rng.uniform(0, 30)
    x, y, theta, v1, v2, i1, i2 = state[rs.PLANT_STATES]
    xr, yr, thetar = state[rs.REFERENCE_STATES]
    vr, wr, vr_dot = velocity(ref, t)
    m = [x, y, theta, 0.5 * k.r / k.R * (v1 - v2), v1, v2, i1, i2, xr, yr, thetar, vr, wr, vr_dot]
    assert rs.measurements(k, ref, t, state[rs.PLANT_STATES], state[rs.REFERENCE_STATES]) == m
    law = control_law(g, state[rs.CONTROLLER_STATES], m)
    expected = [*plant_derivatives(k, t, state[rs.PLANT_STATES], law.u1, law.u2), *law.derivative,
                vr * math.cos(thetar), vr * math.sin(thetar), wr]
    assert rs.closed_loop_derivatives(t, np.array(state), k, g, ref) == pytest.approx(expected, rel=1e-15)
    assert expected[27:] == reference_derivatives(ref, t, state[rs.REFERENCE_STATES])


def test_reference_columns_are_the_circle(paper):
    """(9) with vr = 1, wr = 0.2 from (2, 2, 0): the analytic circle; v_r, omega_r, v_r_dot constant."""
    t = paper["time"]
    rho = 1.0 / 0.2
    np.testing.assert_allclose(paper["x_r"], 2.0 + rho * np.sin(0.2 * t), rtol=0, atol=1e-8)
    np.testing.assert_allclose(paper["y_r"], 2.0 + rho * (1.0 - np.cos(0.2 * t)), rtol=0, atol=1e-8)
    np.testing.assert_allclose(paper["theta_r"], 0.2 * t, rtol=0, atol=1e-8)
    assert np.all(paper["v_r"] == 1.0) and np.all(paper["omega_r"] == 0.2) and np.all(paper["v_r_dot"] == 0.0)


def test_tighter_tolerances_change_little(paper):
    """Self-consistency: rtol = atol = 1e-12 moves the position columns by < 1e-6 m (and heading)."""
    tight = rs.reference_solution(load_scenario("paper"), rtol=1e-12, atol=1e-12)
    for name in POSITION:
        assert np.abs(tight[name] - paper[name]).max() < 1e-6, name


def test_independent_implicit_method_agrees():
    """An implicit solver (Radau) on the same ODE gives the same 5 s trajectory."""
    scenario = load_scenario("paper").with_simulation(stop_time=5.0)
    explicit = rs.reference_solution(scenario)
    implicit = rs.reference_solution(scenario, method="Radau")
    for name in (*POSITION, "omega1", "omega2", "a1_hat", "a2_hat"):
        assert np.abs(implicit[name] - explicit[name]).max() < 1e-7, name
    np.testing.assert_allclose(implicit["u1"], explicit["u1"], rtol=0, atol=1e-5)


def _simpson_residual(result, column, rate):
    """max |column(t + 2h) - column(t) - Simpson integral of rate| over the pairs of steps."""
    h = result["time"][1] - result["time"][0]
    simpson = h / 3 * (rate[:-2:2] + 4 * rate[1:-1:2] + rate[2::2])
    return np.abs(np.diff(result[column][::2]) - simpson).max()


def test_kinematics(paper_dense):
    """Columns x, y, theta obey (1): central differences loosely, Simpson integrals of the rates tightly."""
    r, R = 0.15, 0.75
    res = paper_dense
    speed = 0.5 * r * (res["omega1"] + res["omega2"])
    rates = {"x": speed * np.cos(res["theta"]), "y": speed * np.sin(res["theta"]), "theta": res["theta_dot"]}
    np.testing.assert_allclose(res["theta_dot"], 0.5 * r / R * (res["omega1"] - res["omega2"]), rtol=1e-14, atol=1e-15)
    h = 1e-3
    for name, rate in rates.items():
        central = (res[name][2:] - res[name][:-2]) / (2 * h)
        assert np.abs(central - rate[1:-1]).max() < 1e-2 * np.abs(rate).max(), name
        assert _simpson_residual(res, name, rate) < 1e-8, name


def test_error_surfaces_obey_11(paper_dense):
    """S11, S12 columns evolve as (11) with the recorded wheel speeds (Simpson integral check)."""
    r, R, k1 = 0.15, 0.75, 2.0
    res = paper_dense
    w = 0.5 * r / R * (res["omega1"] - res["omega2"])
    S13bar = res["S13"] - np.arctan(k1 * res["S12"] * res["v_r"])
    np.testing.assert_allclose(np.cos(S13bar), np.cos(res["theta_r"] - res["theta"]), atol=1e-12)
    rate11 = w * res["S12"] - 0.5 * r * (res["omega1"] + res["omega2"]) + res["v_r"] * np.cos(S13bar)
    rate12 = -w * res["S11"] + res["v_r"] * np.sin(S13bar)
    assert _simpson_residual(res, "S11", rate11) < 1e-8
    assert _simpson_residual(res, "S12", rate12) < 1e-8


def test_tracking_errors(paper):
    """docs/model.md §5: xe = xr - x, ye = yr - y, thetae = wrap(thetar - theta) in (-pi, pi], position error."""
    np.testing.assert_array_equal(paper["xe"], paper["x_r"] - paper["x"])
    np.testing.assert_array_equal(paper["ye"], paper["y_r"] - paper["y"])
    np.testing.assert_allclose(paper["position_error"], np.sqrt(paper["xe"] ** 2 + paper["ye"] ** 2), rtol=1e-15)
    diff = paper["theta_r"] - paper["theta"]
    assert np.all((paper["thetae"] > -math.pi) & (paper["thetae"] <= math.pi))
    np.testing.assert_allclose(np.cos(paper["thetae"]), np.cos(diff), atol=1e-12)
    np.testing.assert_allclose(np.sin(paper["thetae"]), np.sin(diff), atol=1e-12)
    assert [wrap(a) for a in diff] == list(paper["thetae"])


def test_controller_outputs_are_the_law(paper):
    """beta, S11, S12 as (10), (14) from the recorded poses; norms of the recorded estimates."""
    k1 = 2.0
    ex, ey, th = paper["xe"], paper["ye"], paper["theta"]
    S11 = np.cos(th) * ex + np.sin(th) * ey
    S12 = -np.sin(th) * ex + np.cos(th) * ey
    np.testing.assert_allclose(paper["S11"], S11, atol=1e-12)
    np.testing.assert_allclose(paper["S12"], S12, atol=1e-12)
    vr = paper["v_r"]
    np.testing.assert_allclose(paper["beta"], 1 + k1 * vr * S11 / (1 + (k1 * S12 * vr) ** 2), atol=1e-12)
    W1 = np.column_stack([paper[f"W1_hat_{i}"] for i in range(1, 9)])
    W2 = np.column_stack([paper[f"W2_hat_{i}"] for i in range(1, 7)])
    np.testing.assert_allclose(paper["W1_hat_norm"], np.linalg.norm(W1, axis=1), rtol=1e-14)
    np.testing.assert_allclose(paper["W2_hat_norm"], np.linalg.norm(W2, axis=1), rtol=1e-14)


@pytest.mark.parametrize("name, stop_time, guarded", [("paper", 30.0, False), ("ahead_start", 3.0, True)])
def test_beta_guard_count(paper, name, stop_time, guarded):
    """The count grows by one at exactly the rows where beta < beta_min: never for the paper,
    from t = 0 when the robot starts ahead of the reference (S11 < 0)."""
    scenario = load_scenario(name)
    res = paper if name == "paper" else rs.reference_solution(scenario.with_simulation(stop_time=stop_time))
    below = res["beta"] < scenario.controller["beta_min"]
    np.testing.assert_array_equal(res["beta_guard_count"], np.cumsum(below))
    assert (res["beta_guard_count"][-1] > 0) == guarded
    if guarded:
        assert res["S11"][0] < 0 and res["beta"][0] < 0 and res["beta_guard_count"][0] == 1


def test_failure_is_a_runtime_error(monkeypatch):
    class Failed:
        success = False
        message = "step size too small"

    monkeypatch.setattr(rs, "solve_ivp", lambda *args, **kwargs: Failed())
    with pytest.raises(RuntimeError, match="step size too small"):
        rs.reference_solution(load_scenario("paper").with_simulation(stop_time=0.1))


@pytest.mark.parametrize(
    "times", [[], [0.2, 0.1], [-0.1, 0.2], [[0.0, 0.1]]], ids=["empty", "descending", "negative", "2d"]
)
def test_bad_times_are_rejected(times):
    with pytest.raises(ValueError, match="times"):
        rs.reference_solution(load_scenario("paper"), times=times)
