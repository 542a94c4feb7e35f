"""The monolithic reference solution: plant, controller and reference robot as one ODE, solved tightly."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from . import signals
from ..models.adaptation import PROJECTION, project_estimates
from ..models.controller import (
    W1_SLICE, W2_SLICE, Gains, control_law, gains, initial_controller_state, start_filters, weight_norm,
)
from ..models.plant import (
    UNLIMITED, PlantCoefficients, applied_voltages, initial_plant_state, plant_coefficients, plant_derivatives,
    saturation, saturation_indicators, theta_dot,
)
from ..models.reference import initial_reference_state, reference_derivatives, velocity
from .. import registry
from ..scenario import Scenario

__all__ = ["output_times", "reference_solution"]

PLANT_STATES = slice(0, 7)
CONTROLLER_STATES = slice(7, 27)
REFERENCE_STATES = slice(27, 30)


def output_times(stop_time: float, output_interval: float) -> np.ndarray:
    """The output grid ``k * output_interval`` for k = 0, 1, ..., ending exactly at ``stop_time``.

    Parameters
    ----------
    stop_time, output_interval : float
        In s.

    Returns
    -------
    numpy.ndarray
        The times in s; the last is ``stop_time`` (after a shorter interval if it is not on the grid).
    """
    n = math.floor(stop_time / output_interval * (1.0 + 1e-12))
    times = np.arange(n + 1) * output_interval
    if stop_time - times[-1] > 1e-9 * output_interval:
        return np.append(times, stop_time)
    times[-1] = stop_time
    return times


def measurements(k: PlantCoefficients, ref_params: dict, t: float, plant: list, reference: list) -> list:
    """The controller's inputs ``m`` (models/controller.py, SI units) from the plant's state (eqs. (6)-(8))
    and the reference's (eq. (9)) at ``t`` (s)."""
    x, y, theta, v1, v2, i1, i2 = plant
    vr, wr, vr_dot = velocity(ref_params, t)
    return [x, y, theta, theta_dot(k, v1, v2), v1, v2, i1, i2, *reference, vr, wr, vr_dot]


def controller_state(g: Gains, state: list) -> list:
    """The controller's 20 states of the closed loop's ``state``; with ``adaptation`` = projection, its
    estimates moved onto their sets, where the solver's error may have taken them (docs/model.md §5.13)."""
    xc = state[CONTROLLER_STATES]
    return project_estimates(g, xc) if g.adaptation == PROJECTION else xc


def closed_loop_derivatives(t: float, state, k: PlantCoefficients, g: Gains, ref_params: dict) -> list:
    """Time derivative of the 30 closed-loop states: plant (6)-(8) driven continuously by ``u`` of (26) through its
    drivers, disturbed at ``t`` (docs/model.md §5.14), controller (15)-(27) fed the current measurements (its
    estimates in their sets: ``controller_state``), reference robot (9)."""
    state = list(state)
    plant, reference = state[PLANT_STATES], state[REFERENCE_STATES]
    law = _law(t, state, k, g, ref_params)
    return [
        *plant_derivatives(k, t, plant, law.u1, law.u2),
        *law.derivative,
        *reference_derivatives(ref_params, t, reference),
    ]


def _law(t: float, state, k: PlantCoefficients, g: Gains, ref_params: dict):
    """The control law at ``t`` and the closed-loop ``state``."""
    state = list(state)
    return control_law(g, controller_state(g, state), measurements(k, ref_params, t, state[PLANT_STATES],
                                                                   state[REFERENCE_STATES]))


def _crossing(index: int):
    """The solver's event function of the drivers' event indicator ``index`` (``saturation_indicators``)."""

    def event(t, state, k, g, ref_params):
        law = _law(t, state, k, g, ref_params)
        return saturation_indicators(k, law.u1, law.u2)[index]

    return event


def _limited_stretches(solution, k: PlantCoefficients, g: Gains, ref_params: dict) -> list:
    """``(start, end)`` in s of each stretch in which a driver limits its voltage: between the roots of the
    indicators, limited where it is at the stretch's middle; adjacent limited stretches joined."""
    edges = sorted({0.0, *np.concatenate(solution.t_events).tolist(), float(solution.t[-1])})
    stretches = []
    for start, end in zip(edges, edges[1:]):
        law = _law(0.5 * (start + end), solution.sol(0.5 * (start + end)), k, g, ref_params)
        if saturation(k, law.u1, law.u2) == UNLIMITED:
            continue
        if stretches and stretches[-1][1] == start:
            stretches[-1] = (stretches[-1][0], end)
        else:
            stretches.append((start, end))
    return stretches


def initial_closed_loop_state(scenario: Scenario) -> list:
    """The 30 states at t = 0 (docs/model.md §5): plant at rest at its initial pose, estimates zero,
    filters started from the t = 0 measurements, reference at its initial pose."""
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    plant, reference = initial_plant_state(scenario.plant), initial_reference_state(scenario.reference)
    m0 = measurements(k, scenario.reference, 0.0, plant, reference)
    return [*plant, *start_filters(g, initial_controller_state(scenario.controller), m0), *reference]


def reference_solution(
    scenario: Scenario, times=None, rtol: float = 1e-10, atol: float = 1e-10, method: str = "DOP853"
) -> np.ndarray:
    """Solve the closed loop as one ODE from t = 0 with SciPy's ``solve_ivp``.

    Parameters
    ----------
    scenario : Scenario
        The scenario.
    times : array_like, optional
        Output times in s, strictly ascending, >= 0; the scenario's output grid by default.
    rtol, atol : float, optional
        The solver's tolerances. Default 1e-10.
    method : str, optional
        Any ``solve_ivp`` method. Default "DOP853".

    Returns
    -------
    numpy.ndarray
        One row per time, dtype ``signals.DTYPE``; ``beta_guard_count`` counts the output rows so far at which
        the beta guard acts (docs/model.md §5). The switches are chosen at each evaluation, as co-simulation
        chooses them; with ``adaptation`` = projection the estimates are those in their sets
        (``controller_state``). With the drivers' limit the solver finds the roots of their indicators
        (docs/model.md §5.14) and integrates across them; ``saturation_count`` counts the stretches between
        them in which a driver limits its voltage, begun by the row's time, ``saturation_time`` their length
        up to it.

    Raises
    ------
    ValueError
        If ``times`` is empty, not ascending or negative.
    RuntimeError
        If the solver fails.
    """
    sim = scenario.simulation
    times = output_times(sim.stop_time, sim.output_interval) if times is None else np.asarray(times, float)
    if times.ndim != 1 or times.size == 0 or times[0] < 0 or np.any(np.diff(times) <= 0):
        raise ValueError("times must be a non-empty, strictly ascending sequence of times >= 0")
    k, g, ref = plant_coefficients(scenario.plant), gains(scenario.controller), scenario.reference
    limited = k.u_max is not None
    events = {"events": [_crossing(i) for i in range(4)], "dense_output": True} if limited else {}
    solution = solve_ivp(
        closed_loop_derivatives, (0.0, times[-1]), initial_closed_loop_state(scenario),
        method=method, t_eval=times, args=(k, g, ref), rtol=rtol, atol=atol, **events,
    )
    if not solution.success:
        raise RuntimeError(f"reference solution of {scenario.name!r} failed: {solution.message}")
    stretches = _limited_stretches(solution, k, g, ref) if limited else []

    rows = []
    guard_count = 0
    for t, state in zip(solution.t, solution.y.T):
        state = list(state)
        xc = controller_state(g, state)
        m = measurements(k, ref, t, state[PLANT_STATES], state[REFERENCE_STATES])
        law = control_law(g, xc, m)
        guard_count += law.guarded
        W1_hat, W2_hat = xc[W1_SLICE], xc[W2_SLICE]
        controller = [  # as the controller FMU's outputs()
            law.u1, law.u2, law.S11, law.S12, law.S13, law.beta, xc[0], xc[1],
            weight_norm(W1_hat), weight_norm(W2_hat), *W1_hat, *W2_hat, guard_count,
        ]
        drives = [  # as the plant FMU's outputs() and saturation_count
            *applied_voltages(k, law.u1, law.u2),
            math.fsum(min(end, t) - start for start, end in stretches if start < t),
            sum(start <= t for start, _ in stretches),
        ]
        rows.append({
            "time": t,
            **dict(zip(signals.RECORDED[registry.PLANT], [*m[:8], *drives], strict=True)),
            **dict(zip(signals.RECORDED[registry.REFERENCE], m[8:], strict=True)),
            **dict(zip(signals.RECORDED[registry.CONTROLLER], controller, strict=True)),
        })
    result = np.zeros(len(rows), dtype=signals.DTYPE)
    for name in signals.COLUMNS:
        if name not in signals.DERIVED:
            result[name] = [row[name] for row in rows]
    signals.add_tracking_errors(result)
    return result
