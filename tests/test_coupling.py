"""The FMUs' ``coupling`` parameter: inputs held, extrapolated or interpolated over a step, checked
against independent integrations of the model with those inputs; the history is part of the FMU state."""

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from scipy.integrate import solve_ivp

from dsc_fmu.cosim.master import Cosimulator

from dsc_fmu.models import parameters as P
from dsc_fmu.models.controller import control_law, gains, initial_controller_state, start_filters
from dsc_fmu.models.plant import plant_coefficients, plant_derivatives
from dsc_fmu.scenario import ScenarioError, load_scenario
from drives import CONTROLLER, CONTROLLER_IN, M_OTHER, M_PAPER, PLANT
from test_fmus import Instance, md, new  # noqa: F401 (fixtures)

HOLD, EXTRAPOLATE, INTERPOLATE = range(3)
FINE = 1e-6  # s: max_step of the FMUs here, so that RK4 is exact to rounding
H = 2e-3
U0, U1, U2 = (40.0, 25.0), (55.0, -10.0), (20.0, 30.0)


def _solve(f, t0, x0, t1):
    return solve_ivp(f, (t0, t1), x0, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]


def _plant_step(x, t0, u_at):
    c = plant_coefficients(PLANT)
    return _solve(lambda t, s: plant_derivatives(c, t, list(s), *u_at(t)), t0, x, t0 + H)


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


@pytest.mark.parametrize("name,inputs,values,coupling,pending", [
    ("MobileRobot", ("u1", "u2"), (U0, U1, U2, U0), EXTRAPOLATE, False),
    ("DSCController", CONTROLLER_IN, (M_PAPER, M_OTHER, M_PAPER, M_OTHER), EXTRAPOLATE, False),
    ("DSCController", CONTROLLER_IN, (M_PAPER, M_OTHER, M_PAPER, M_OTHER), INTERPOLATE, False),
    ("MobileRobot", ("u1", "u2"), (U0, U1, U2, U0), HOLD, True),
], ids=["plant-extrapolate", "controller-extrapolate", "controller-interpolate", "plant-pending-derivatives"])
def test_the_input_history_is_part_of_the_fmu_state(new, name, inputs, values, coupling, pending):
    """Rolled back to a saved state, a linear-coupled FMU repeats its steps exactly (the line of the
    inputs starts from the saved history, or from input derivatives set before the state was
    saved), also from a serialized state in a new instance."""
    inst = new(name, integer={"coupling": coupling})
    for k, value in enumerate(values[:2]):
        inst.set(inputs, value)
        inst.step(k * H, H)
    if pending:
        inst.set(inputs, values[2])
        inst.fmu.setRealInputDerivatives([inst.vr[n] for n in inputs], [1] * len(inputs), [3000.0, -2000.0])
    state = inst.fmu.getFMUstate()
    serialized = inst.fmu.serializeFMUstate(state)

    def step_on(instance):
        if not pending:
            instance.set(inputs, values[2])
        instance.step(2 * H, H)
        instance.set(inputs, values[3])
        instance.step(3 * H, H / 2)  # another step size after a rollback: the slope still spans the last points
        return instance.outputs()

    first = step_on(inst)
    inst.fmu.setFMUstate(state)
    assert step_on(inst) == first
    if pending:  # the derivatives did act: without them the same step holds u
        plain = new(name, integer={"coupling": coupling}, label="plain")
        plain.fmu.setFMUstate(state)
        plain.fmu.setRealInputDerivatives([plain.vr[n] for n in inputs], [1] * len(inputs), [0.0] * len(inputs))
        assert step_on(plain) != first
    other = new(name, integer={"coupling": coupling}, label="restored")
    other.fmu.setFMUstate(other.fmu.deSerializeFMUstate(serialized))
    assert step_on(other) == first
    inst.fmu.freeFMUstate(state)


def test_the_coupling_parameters_are_fixed_integers_with_named_choices():
    for table, count in ((P.PLANT_PARAMETERS, 2), (P.CONTROLLER_PARAMETERS, 3)):
        coupling = {v.name: v for v in table}["coupling"]
        assert coupling.integer and not coupling.tunable and coupling.start == HOLD
        assert coupling.choices == P.INPUT_COUPLINGS[:count] and coupling.maximum == count - 1
    assert np.array_equal(P.INPUT_COUPLINGS, ("hold", "extrapolate", "interpolate"))


# --- the standard route: canInterpolateInputs and fmi2SetRealInputDerivatives ---------------------

def test_input_derivatives_after_termination_are_refused(new):
    """Allowed in instantiated, initialization mode and stepComplete only (FMI 2.0.4, 4.2.4)."""
    plant = new("MobileRobot")
    plant.fmu.terminate()
    with pytest.raises(FMICallException):
        plant.fmu.setRealInputDerivatives([plant.vr["u1"]], [1], [1.0])
    assert any("fmi2SetRealInputDerivatives is not allowed in state terminated" in text
               for _, text in plant.messages())


def test_fmus_with_inputs_declare_that_they_interpolate_inputs(md):
    assert {name: description.coSimulation.canInterpolateInputs for name, description in md.items()} == {
        "ReferenceRobot": False, "MobileRobot": True, "DSCController": True}


def test_an_input_derivative_sets_the_slope_of_the_next_step_only(new):
    """Through the project's binary: u(t) = u_k + d (t - t_k) over the next step, then held again."""
    slopes = (2000.0, -1500.0)
    plant = new("MobileRobot", real={"max_step": FINE})
    vr = [plant.vr["u1"], plant.vr["u2"]]
    plant.set(("u1", "u2"), U1)
    plant.fmu.setRealInputDerivatives(vr, [1, 1], list(slopes))
    plant.step(0.0, H)
    plant.step(H, H)
    x = [PLANT["x0"], PLANT["y0"], PLANT["theta0"], 0.0, 0.0, 0.0, 0.0]
    x = _plant_step(x, 0.0, lambda t: [u + d * t for u, d in zip(U1, slopes)])
    x = _plant_step(x, H, lambda t: U1)
    assert plant.get(("x", "y", "theta", "omega1", "omega2", "i1", "i2")) == pytest.approx(list(x), rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("vr_name,order,message", [
    ("u1", 2, "derivative order 2 of u1 is not allowed; allowed: 1"),
    ("x0", 1, "is not a Real input"),
])
def test_a_wrong_input_derivative_is_an_error_naming_it(new, vr_name, order, message):
    plant = new("MobileRobot")
    with pytest.raises(FMICallException):
        plant.fmu.setRealInputDerivatives([plant.vr[vr_name]], [order], [1.0])
    assert any(message in text for _, text in plant.messages())


def test_the_master_takes_the_standard_route_to_the_same_coupling(fmu_paths, fmu3_paths):
    """Jacobi: the same run bit for bit as with the coupling parameters; Gauss-Seidel: the same but
    for the first step (the route interpolates it from the start, the parameters hold it)."""
    scenario = load_scenario("paper").with_simulation(stop_time=2.0, step_size=2e-3, coupling="linear")
    with Cosimulator(fmu_paths) as simulator:
        jacobi = [simulator.run(scenario, order="jacobi", input_derivatives=route).result for route in (False, True)]
        np.testing.assert_array_equal(*jacobi)
        seidel = [simulator.run(scenario, input_derivatives=route).result for route in (False, True)]
        for name in ("x", "y", "theta"):
            np.testing.assert_allclose(seidel[0][name], seidel[1][name], rtol=0, atol=1e-4)
        with pytest.raises(ScenarioError, match=r"input_derivatives = true realises the linear coupling at a fixed "
                           r"step; allowed: with coupling = \"linear\" and no tolerance \(here coupling = \"hold\"\)$"):
            simulator.run(scenario, coupling="hold", input_derivatives=True)
    with Cosimulator(fmu3_paths) as simulator, pytest.raises(ScenarioError, match="input_derivatives = true needs FMI 2.0"):
        simulator.run(scenario, input_derivatives=True)
    routed, names = scenario.with_simulation(input_derivatives=True), ("ReferenceRobot", "MobileRobot", "DSCController")
    assert [routed.parameters(name).get("coupling") for name in names] == [None, 1, 2]  # what other masters get
    assert [routed.parameters(name, slopes_from_master=True).get("coupling") for name in names] == [None, 0, 0]
