"""The FMUs' ``coupling`` parameter: inputs held, extrapolated or interpolated over a step, checked
against independent integrations of the model with those inputs; the history is part of the FMU state."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from dsc_fmu.models import parameters as P
from dsc_fmu.models.controller import control_law, gains, initial_controller_state, start_filters
from dsc_fmu.models.plant import plant_coefficients, plant_derivatives
from test_fmus import CONTROLLER, CONTROLLER_IN, M_OTHER, M_PAPER, PLANT, md, new  # noqa: F401 (fixtures)

HOLD, EXTRAPOLATE, INTERPOLATE = range(3)
FINE = 1e-6  # s: max_step of the FMUs here, so that RK4 is exact to rounding
H = 2e-3
U0, U1, U2 = (40.0, 25.0), (55.0, -10.0), (20.0, 30.0)


def _solve(f, t0, x0, t1):
    return solve_ivp(f, (t0, t1), x0, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]


def _plant_step(x, t0, u_at):
    c = plant_coefficients(PLANT)
    return _solve(lambda t, s: plant_derivatives(c, list(s), *u_at(t)), t0, x, t0 + H)


def _line(t_then, then, t_now, now):
    """The line through (t_then, then) and (t_now, now), as a function of t."""
    return lambda t: [b + (t - t_now) * (b - a) / (t_now - t_then) for a, b in zip(then, now)]


@pytest.mark.parametrize("coupling", [HOLD, EXTRAPOLATE], ids=["hold", "extrapolate"])
def test_plant_holds_or_extrapolates_u_from_the_last_two_points(new, coupling):
    plant = new("MobileRobot", real={"max_step": FINE}, integer={"coupling": coupling})
    x = [PLANT["x0"], PLANT["y0"], PLANT["theta0"], 0.0, 0.0, 0.0, 0.0]
    for k, u in enumerate((U0, U1, U2)):
        plant.set(("u1", "u2"), u)
        plant.step(k * H, H)
        if k == 0 or coupling == HOLD:
            x = _plant_step(x, k * H, lambda t, u=u: u)  # the first step holds
        else:
            x = _plant_step(x, k * H, _line((k - 1) * H, (U0, U1)[k - 1], k * H, u))
        state = plant.get(("x", "y", "theta", "omega1", "omega2", "i1", "i2"))
        assert state == pytest.approx(list(x), rel=1e-9, abs=1e-12), k


def _controller_steps(coupling, inputs):
    """The controller's state after each step of H with ``inputs`` set before each, integrated here."""
    g = gains(CONTROLLER)
    x = start_filters(g, initial_controller_state(CONTROLLER), inputs[0])
    states = []
    for k, m in enumerate(inputs):
        t0 = k * H
        if k == 0 or coupling == HOLD:
            m_at = lambda t, m=m: m  # noqa: E731
        elif coupling == EXTRAPOLATE:  # set for the step's start: stamped t0
            m_at = _line(t0 - H, inputs[k - 1], t0, m)
        else:  # set for the step's end: stamped t0 + H, the previous ones t0
            m_at = _line(t0, inputs[k - 1], t0 + H, m)
        x = list(_solve(lambda t, s: control_law(g, list(s), m_at(t)).derivative, t0, x, t0 + H))
        states.append(x)
    return states


@pytest.mark.parametrize("coupling", [HOLD, EXTRAPOLATE, INTERPOLATE], ids=["hold", "extrapolate", "interpolate"])
def test_controller_integrates_with_held_extrapolated_or_interpolated_inputs(new, coupling):
    inputs = [M_PAPER, M_OTHER, [m + 0.01 * i for i, m in enumerate(M_OTHER)]]
    ctrl = new("DSCController", real={"max_step": FINE}, integer={"coupling": coupling})
    expected = _controller_steps(coupling, inputs)
    g = gains(CONTROLLER)
    for k, m in enumerate(inputs):
        ctrl.set(CONTROLLER_IN, m)
        ctrl.step(k * H, H)
        law = control_law(g, expected[k], m)  # u at the step's end: the state there, the inputs set
        assert ctrl.get(("u1", "u2", "a1_hat", "a2_hat")) == pytest.approx(
            [law.u1, law.u2, expected[k][0], expected[k][1]], rel=1e-8, abs=1e-10), k
    if coupling != HOLD:
        held = _controller_steps(HOLD, inputs)[-1]
        assert control_law(g, held, inputs[-1]).u1 != pytest.approx(ctrl.get1("u1"), rel=1e-6)


@pytest.mark.parametrize("name,inputs,values", [
    ("MobileRobot", ("u1", "u2"), (U0, U1, U2, U0)),
    ("DSCController", CONTROLLER_IN, (M_PAPER, M_OTHER, M_PAPER, M_OTHER)),
])
def test_the_input_history_is_part_of_the_fmu_state(new, name, inputs, values):
    """Rolled back to a saved state, a linear-coupled FMU repeats its steps exactly (the line of the
    inputs starts from the saved history), also from a serialized state in a new instance."""
    coupling = EXTRAPOLATE
    inst = new(name, integer={"coupling": coupling})
    for k, value in enumerate(values[:2]):
        inst.set(inputs, value)
        inst.step(k * H, H)
    state = inst.fmu.getFMUstate()
    serialized = inst.fmu.serializeFMUstate(state)

    def step_on(instance):
        instance.set(inputs, values[2])
        instance.step(2 * H, H)
        instance.set(inputs, values[3])
        instance.step(3 * H, H / 2)  # another step size after a rollback: the slope still spans the last points
        return instance.outputs()

    first = step_on(inst)
    inst.fmu.setFMUstate(state)
    assert step_on(inst) == first
    other = new(name, integer={"coupling": coupling}, label="restored")
    other.fmu.setFMUstate(other.fmu.deSerializeFMUstate(serialized))
    assert step_on(other) == first
    inst.fmu.freeFMUstate(state)


def test_the_coupling_parameters_are_fixed_integers_with_named_choices():
    for table, count in ((P.PLANT_PARAMETERS, 2), (P.CONTROLLER_PARAMETERS, 3)):
        coupling = {v.name: v for v in table}["coupling"]
        assert coupling.integer and not coupling.tunable and coupling.start == HOLD
        assert coupling.choices == P.COUPLINGS[:count] and coupling.maximum == count - 1
    assert np.array_equal(P.COUPLINGS, ("hold", "extrapolate", "interpolate"))
