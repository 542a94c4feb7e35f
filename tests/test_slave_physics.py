"""What the slaves compute, in this process: the plant, the reference robot and the control law through the slave.

The slave classes of ``fmu_sources`` driven as the binary drives them (``in_process``); what only the
binary does is in test_fmus.py. Expectations come from closed-form solutions of the equations in
docs/model.md and from ``dsc_fmu.models`` called directly, never from numbers copied from the slaves' output.
"""

import math

import pytest
from fmpy import read_model_description

from dsc_fmu.models import parameters as P
from dsc_fmu.models.controller import control_law, gains, initial_controller_state, start_filters
from drives import CONTROLLER, CONTROLLER_IN, M_OTHER, M_PAPER, PLANT, PLANT_OUT
from in_process import InProcess, new  # noqa: F401 (new: a fixture)

REFERENCE = P.defaults(P.REFERENCE_PARAMETERS)
REFERENCE_OUT = tuple(v.name for v in P.REFERENCE_OUTPUTS)


@pytest.fixture(scope="module")
def md(fmu_paths):
    return {name: read_model_description(str(path)) for name, path in fmu_paths.items()}


# --- feedthrough and dependencies ---------------------------------------------------------------


def test_plant_outputs_do_not_move_with_the_inputs_but_the_applied_voltages(new):
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (3.0, -2.0))
    plant.step(0.0, 0.01)
    before = plant.outputs()
    plant.set(("u1", "u2"), (50.0, 40.0))
    assert plant.outputs() == {**before, "u1_applied": 50.0, "u2_applied": 40.0}


def test_controller_outputs_move_only_with_their_declared_inputs(md, new):
    """Perturb each input: outputs that do not list it among their dependencies must not change."""
    deps = {u.variable.name: {d.name for d in u.dependencies} for u in md["DSCController"].outputs}
    ctrl = new("DSCController")
    ctrl.set(CONTROLLER_IN, M_OTHER)
    for k in range(3):
        ctrl.step(k * 1e-3, 1e-3)
    base = ctrl.outputs()
    assert all(math.isfinite(float(v)) for v in base.values())
    moved = {name: set() for name in base}
    for i, name in enumerate(CONTROLLER_IN):
        m = list(M_OTHER)
        m[i] += 0.05
        ctrl.set(CONTROLLER_IN, m)
        now = ctrl.outputs()
        for out in base:
            if now[out] != base[out]:
                moved[out].add(name)
        ctrl.set(CONTROLLER_IN, M_OTHER)
    assert ctrl.outputs() == base
    assert {out: sorted(moved[out] - deps[out]) for out in base} == {out: [] for out in base}
    # The voltages do react to the pose and the reference within the same communication point.
    assert {"x", "y", "theta", "x_r", "y_r", "theta_r", "v_r", "i1", "i2"} <= moved["u1"] | moved["u2"]


def test_controller_direct_feedthrough(new):
    """Once stepped, the filter states are fixed by the first step (docs/model.md §5: the first measurements
    seen); from then on u follows every new input vector at the current state."""
    ctrl = new("DSCController")
    g = gains(CONTROLLER)
    ctrl.set(CONTROLLER_IN, M_PAPER)
    ctrl.step(0.0, 1e-3)
    state = [ctrl.get1(name) for name in ("a1_hat", "a2_hat")]
    results = []
    for m in (M_PAPER, M_OTHER):
        ctrl.set(CONTROLLER_IN, m)
        u = ctrl.get(("u1", "u2"))
        assert [ctrl.get1(name) for name in ("a1_hat", "a2_hat")] == state
        assert all(math.isfinite(x) for x in u)
        results.append(u)
    ctrl.set(CONTROLLER_IN, M_PAPER)
    assert ctrl.get(("u1", "u2")) == results[0]
    fresh = control_law(g, start_filters(g, initial_controller_state(CONTROLLER), M_OTHER), M_OTHER)
    assert results[1] != pytest.approx([fresh.u1, fresh.u2], rel=1e-9)
    assert results[0][0] != results[1][0] and results[0][1] != results[1][1]


def test_controller_state_follows_inputs_until_the_first_step():
    """Until the first step, x2f = x2bar and x3f = x3bar of the current inputs, in
    initialisation mode and after it, whatever was read before; the first step starts from the
    inputs it holds (so no order of sets and reads can latch stale start values)."""
    inst = InProcess("DSCController", label="init")
    g = gains(CONTROLLER)
    inst.slave.setup_experiment(0.0)
    inst.slave.enter_initialization_mode()

    def expect(m, state=None):
        x = state or start_filters(g, initial_controller_state(CONTROLLER), m)
        law = control_law(g, x, m)
        assert inst.get(("u1", "u2")) == pytest.approx([law.u1, law.u2], rel=1e-12, abs=1e-12)

    for m in (M_PAPER, M_OTHER):
        inst.set(CONTROLLER_IN, m)
        expect(m)
    inst.slave.exit_initialization_mode()
    for m in (M_PAPER, M_OTHER):
        inst.set(CONTROLLER_IN, m)
        expect(m)
    assert inst.outputs()["started"] is False
    inst.step(0.0, 1e-3)
    assert inst.outputs()["started"] is True


def test_euler_discretization_takes_one_explicit_euler_step(new):
    """discretization = 1: the controller state after a step is x + h f(x) with the inputs held."""
    h = 5e-3
    g = gains(CONTROLLER)
    state = start_filters(g, initial_controller_state(CONTROLLER), M_PAPER)
    euler = [x + h * d for x, d in zip(state, control_law(g, state, M_PAPER).derivative)]
    expected = control_law(g, euler, M_PAPER)
    ctrl = new("DSCController", integer={"discretization": 1})
    ctrl.set(CONTROLLER_IN, M_PAPER)
    ctrl.step(0.0, h)
    assert ctrl.get(("u1", "u2", "a1_hat", "a2_hat")) == pytest.approx(
        [expected.u1, expected.u2, euler[0], euler[1]], rel=1e-12, abs=1e-12)
    rk4 = new("DSCController")
    rk4.set(CONTROLLER_IN, M_PAPER)
    rk4.step(0.0, h)
    assert rk4.get1("a1_hat") != pytest.approx(euler[0], rel=1e-9)


def test_initial_state_parameters_set_the_state_at_t0(new):
    """omega1_0 ... i2_0 and a1_hat0 ... W2_hat0_6 start the plant and the estimates (docs/model.md §5 defaults: 0)."""
    plant = new("MobileRobot", real={"omega1_0": 7.5, "omega2_0": 5.5, "i1_0": 2.0, "i2_0": -1.0})
    assert plant.get(("omega1", "omega2", "i1", "i2")) == [7.5, 5.5, 2.0, -1.0]
    assert plant.get1("theta_dot") == pytest.approx(0.5 * PLANT["r"] / PLANT["R"] * 2.0, rel=1e-15)
    estimates = {"a1_hat0": 8.0, "a2_hat0": 6.0, "W1_hat0_3": 0.05, "W2_hat0_1": 1.6}
    ctrl = new("DSCController", real=estimates)
    ctrl.set(CONTROLLER_IN, M_PAPER)
    assert ctrl.get(("a1_hat", "a2_hat", "W1_hat_3", "W2_hat_1")) == list(estimates.values())
    state = start_filters(gains(CONTROLLER), initial_controller_state({**CONTROLLER, **estimates}), M_PAPER)
    law = control_law(gains(CONTROLLER), state, M_PAPER)
    assert ctrl.get(("u1", "u2")) == pytest.approx([law.u1, law.u2], rel=1e-12)


# --- the plant, the reference robot, the sub-steps ----------------------------------------------


def _steady_speed(U, wheel):
    """Steady wheel speed and current under constant voltage U with equal wheels (docs/model.md §1)."""
    nkt = PLANT[f"N{wheel}"] * PLANT[f"KT{wheel}"]
    nke = PLANT[f"N{wheel}"] * PLANT[f"KE{wheel}"]
    ra, damping = PLANT[f"Ra{wheel}"], PLANT[f"d{wheel}{wheel}"]
    v = nkt * U / (ra * damping + nkt * nke)
    return v, (U - nke * v) / ra


@pytest.mark.parametrize("U,theta0", [(10.0, None), (-6.0, 0.7)], ids=["U=10,theta0=table", "U=-6,theta0=0.7"])
def test_plant_reaches_the_analytic_steady_state(new, U, theta0):
    real = {} if theta0 is None else {"theta0": theta0}
    heading = PLANT["theta0"] if theta0 is None else theta0
    plant = new("MobileRobot", real=real)
    plant.set(("u1", "u2"), (U, U))
    h = 0.01
    for k in range(200):
        plant.step(k * h, h)
    at2 = dict(zip(PLANT_OUT, plant.get(PLANT_OUT)))
    for k in range(200, 300):
        plant.step(k * h, h)
    at3 = dict(zip(PLANT_OUT, plant.get(PLANT_OUT)))
    for wheel in (1, 2):
        v, i = _steady_speed(U, wheel)
        assert at3[f"omega{wheel}"] == pytest.approx(v, rel=1e-9)
        assert at3[f"i{wheel}"] == pytest.approx(i, rel=1e-9)
    v = _steady_speed(U, 1)[0]
    assert at3["theta_dot"] == pytest.approx(0.0, abs=1e-12)
    assert at3["theta"] == pytest.approx(heading, abs=1e-12)
    # Over the last second it moves along its heading at r v.
    distance = PLANT["r"] * v * 1.0
    assert at3["x"] - at2["x"] == pytest.approx(distance * math.cos(heading), rel=1e-9, abs=1e-12)
    assert at3["y"] - at2["y"] == pytest.approx(distance * math.sin(heading), rel=1e-9, abs=1e-12)


def test_plant_turns_in_place_without_offset_mass(new):
    """u1 = -u2 with d = 0 (no Coriolis coupling): v1 = -v2, the axle midpoint stays put."""
    plant = new("MobileRobot", real={"d": 0.0})
    plant.set(("u1", "u2"), (10.0, -10.0))
    for k in range(50):
        plant.step(k * 0.01, 0.01)
    out = dict(zip(PLANT_OUT, plant.get(PLANT_OUT)))
    assert out["x"] == pytest.approx(PLANT["x0"], abs=1e-12)
    assert out["y"] == pytest.approx(PLANT["y0"], abs=1e-12)
    assert out["omega1"] == pytest.approx(-out["omega2"], abs=1e-12)
    assert out["omega1"] > 0 and out["theta_dot"] > 0 and out["theta"] > PLANT["theta0"] + 0.01
    # theta_dot = r / (2R) (v1 - v2), eq. (1)
    assert out["theta_dot"] == pytest.approx(PLANT["r"] / (2 * PLANT["R"]) * (out["omega1"] - out["omega2"]), rel=1e-12)


def test_plant_short_turn_with_paper_parameters(new):
    """With the paper's d > 0 a short u1 = -u2 step still turns essentially in place."""
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (10.0, -10.0))
    for k in range(10):
        plant.step(k * 0.005, 0.005)
    out = dict(zip(PLANT_OUT, plant.get(PLANT_OUT)))
    turned = out["theta"] - PLANT["theta0"]
    moved = math.hypot(out["x"] - PLANT["x0"], out["y"] - PLANT["y0"])
    assert turned > 1e-3
    assert moved < 1e-3 * PLANT["R"] * turned


def _circle(t, x0, y0, theta0, v, w):
    return (
        x0 + v / w * (math.sin(theta0 + w * t) - math.sin(theta0)),
        y0 - v / w * (math.cos(theta0 + w * t) - math.cos(theta0)),
        theta0 + w * t,
    )


@pytest.mark.parametrize("real", [{}, {"vr0": 0.5, "wr0": -0.4, "theta0": 1.0, "x0": -1.0, "y0": 0.5}],
                         ids=["table", "custom"])
def test_reference_constant_profile_follows_the_circle(new, real):
    p = {**REFERENCE, **real}
    ref = new("ReferenceRobot", real=real)
    h, t, checked = 0.05, 0.0, 0
    assert ref.get(REFERENCE_OUT[:3]) == pytest.approx([p["x0"], p["y0"], p["theta0"]], abs=1e-15)
    for k in range(1, 401):
        ref.step(t, h)
        t = k * h
        if k % 50 == 0:
            out = dict(zip(REFERENCE_OUT, ref.get(REFERENCE_OUT)))
            expected = _circle(t, p["x0"], p["y0"], p["theta0"], p["vr0"], p["wr0"])
            assert [out["x_r"], out["y_r"], out["theta_r"]] == pytest.approx(expected, abs=1e-9)
            assert (out["v_r"], out["omega_r"], out["v_r_dot"]) == (p["vr0"], p["wr0"], 0.0)
            checked += 1
    assert checked == 8


def _eight(t, A, B, T):
    W = 2 * math.pi / T
    x, y = A * math.sin(W * t), B * math.sin(2 * W * t)
    xd, yd = A * W * math.cos(W * t), 2 * B * W * math.cos(2 * W * t)
    return x, y, math.hypot(xd, yd)


def test_reference_figure_eight_traces_the_curve(new):
    """Started on the curve's initial tangent, the reference robot traces x0 + A sin(Wt), y0 + B sin(2Wt)."""
    A, B, T = REFERENCE["eight_A"], REFERENCE["eight_B"], REFERENCE["eight_T"]
    theta0 = math.atan2(2 * B, A)
    ref = new("ReferenceRobot", real={"theta0": theta0}, integer={"profile": 1})
    h, accelerating = 0.1, []
    for k in range(int(round(T / h))):
        ref.step(k * h, h)
        t = (k + 1) * h
        out = dict(zip(REFERENCE_OUT, ref.get(REFERENCE_OUT)))
        x, y, speed = _eight(t, A, B, T)
        assert out["v_r"] > 0
        assert out["v_r"] == pytest.approx(speed, rel=1e-12)
        if (k + 1) % 25 == 0:
            assert [out["x_r"] - REFERENCE["x0"], out["y_r"] - REFERENCE["y0"]] == pytest.approx([x, y], abs=1e-8)
        accelerating.append(abs(out["v_r_dot"]) > 1e-3)
    assert any(accelerating)


def test_reference_profile_starts_at_the_experiments_start_time():
    A, B, T = REFERENCE["eight_A"], REFERENCE["eight_B"], REFERENCE["eight_T"]
    ref = InProcess("ReferenceRobot", label="t5").initialize(integer={"profile": 1}, start_time=5.0)
    assert ref.get(REFERENCE_OUT[:3]) == [REFERENCE["x0"], REFERENCE["y0"], REFERENCE["theta0"]]
    assert ref.get1("v_r") == pytest.approx(_eight(5.0, A, B, T)[2], rel=1e-12)
    ref.step(5.0, 0.1)
    assert ref.get1("v_r") == pytest.approx(_eight(5.1, A, B, T)[2], rel=1e-12)


def test_reference_figure_eight_closes_after_one_period(new):
    T = REFERENCE["eight_T"]
    ref = new("ReferenceRobot", integer={"profile": 1})
    start = ref.get(REFERENCE_OUT)
    h = 0.1
    quarter = None
    for k in range(int(round(T / h))):
        ref.step(k * h, h)
        if k + 1 == int(round(T / h)) // 4:
            quarter = ref.get(REFERENCE_OUT)  # the tip of a lobe, A away from the centre
    end = ref.get(REFERENCE_OUT)
    assert end[:3] == pytest.approx(start[:3], abs=1e-8)
    assert end[3:5] == pytest.approx(start[3:5], rel=1e-9, abs=1e-12)
    # ... and it went somewhere in between (a figure, not a point).
    assert math.hypot(quarter[0] - start[0], quarter[1] - start[1]) == pytest.approx(REFERENCE["eight_A"], rel=1e-6)




def test_max_step_sets_the_rk4_sub_steps(new):
    one = new("MobileRobot", real={"max_step": 1e-3})
    many = new("MobileRobot", real={"max_step": 1e-3})
    coarse = new("MobileRobot", real={"max_step": 0.1})
    for inst in (one, many, coarse):
        inst.set(("u1", "u2"), (12.0, 7.0))
    one.step(0.0, 0.1)
    for k in range(100):
        many.step(k * 1e-3, 1e-3)
    coarse.step(0.0, 0.1)
    fine = one.get(PLANT_OUT)
    assert fine == pytest.approx(many.get(PLANT_OUT), rel=1e-12, abs=1e-12)
    rough = coarse.get(PLANT_OUT)
    assert all(math.isfinite(v) for v in rough)
    assert abs(rough[4] - fine[4]) > 1e-3 * abs(fine[4])  # omega1: a single RK4 step of 0.1 s is far off
