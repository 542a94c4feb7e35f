"""What the slaves decide, in this process: refusals, discarded steps, the beta guard, the wait for valid inputs,
FMU state and the messages they log.

The slave classes of ``fmu_sources`` (FMI 2.0 on pythonfmu, FMI 3.0 on pythonfmu3) driven as the binary
drives them (``in_process``); test_fmus.py keeps what only the binary does (the importer's logger, the
state machine after a discarded step, serialized state through ctypes).
"""

import math
import re

import pytest

from dsc_fmu.fmu import native_bridge
from dsc_fmu.models import parameters as P
from dsc_fmu.models.controller import control_law, gains, initial_controller_state, start_filters
from dsc_fmu.models.rk4 import MAX_SUBSTEPS
from drives import CONTROLLER, CONTROLLER_IN, DRIVES, M_GUARD, M_PAPER, NAMES, PLANT, PLANT_OUT, replay
from in_process import Discarded, InProcess, new  # noqa: F401 (new: a fixture)

OK, WARNING, DISCARD, ERROR = range(4)
VALID_INPUTS = P.START_ON.index("valid_inputs")


# --- FMU state ----------------------------------------------------------------------------------


@pytest.mark.parametrize("fmi_version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_get_and_set_fmu_state_replays_identically(new, name, fmi_version):
    integer, inputs, schedule = DRIVES[name]
    inst = new(name, integer=integer, fmi_version=fmi_version)
    h = 2e-3
    replay(inst, inputs, schedule, 0.0, 5, h)
    state = inst.get_state()
    first = replay(inst, inputs, schedule, 5 * h, 6, h)
    inst.set_state(state)
    second = replay(inst, inputs, schedule, 5 * h, 6, h)
    assert second == first
    assert first[0] != first[-1]
    if name == "DSCController":
        assert first[-1]["beta_guard_count"] > first[0]["beta_guard_count"] > 0


@pytest.mark.parametrize("name", NAMES)
def test_fmu_state_before_the_first_step(new, name):
    integer, inputs, schedule = DRIVES[name]
    inst = new(name, integer=integer)
    state = inst.get_state()
    first = replay(inst, inputs, schedule, 0.0, 4, 1e-3)
    inst.set_state(state)
    assert replay(inst, inputs, schedule, 0.0, 4, 1e-3) == first


def _through_bytes(inst, state):
    """``state`` serialized as the binary serializes it, and read back."""
    return native_bridge.state_from_bytes(inst.slave, native_bridge.state_to_bytes(inst.slave, state))


def test_input_derivatives_given_for_the_next_step_are_part_of_the_fmu_state(new):
    """Given by input index; JSON gives the indices back as strings and the restored state takes them."""
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (4.0, 5.0))
    plant.slave.set_input_derivatives([plant.vr["u2"]], [1], [300.0])
    state = _through_bytes(plant, plant.get_state())
    other = new("MobileRobot")
    other.set_state(state)
    held = new("MobileRobot")
    held.set(("u1", "u2"), (4.0, 5.0))
    for inst in (plant, other, held):
        inst.step(0.0, 0.01)
    assert other.get(PLANT_OUT) == plant.get(PLANT_OUT) != held.get(PLANT_OUT)


def test_held_switches_of_model_exchange_round_trip_through_bytes(new):
    """The switches held since the last event (a named tuple, a list after JSON) come back as they were."""
    ctrl = new("DSCController")
    ctrl.set(CONTROLLER_IN, M_GUARD)
    ctrl.slave.start_continuous_time()
    ctrl.set(CONTROLLER_IN, M_PAPER)  # no event: the guard's switch stays held
    other = new("DSCController")
    other.set_state(_through_bytes(ctrl, ctrl.get_state()))
    assert other.slave.model.held == ctrl.slave.model.held and other.slave.model.held.guarded
    assert other.slave.get_derivatives() == ctrl.slave.get_derivatives()
    assert other.outputs() == ctrl.outputs()


def test_the_projection_held_at_an_event_round_trips_through_bytes(new):
    """At an event the estimates outside their sets are moved onto them (the slave reports the change) and the
    projection's switches are held; both come back from bytes as they were."""
    sets = {"a1_min": -1.0, "a1_max": 1.0, "a2_min": -1.0, "a2_max": 1.0, "W1_max": 0.5, "W2_max": 0.5}
    ctrl = new("DSCController", real=sets, integer={"adaptation": P.ADAPTATIONS.index("projection")})
    ctrl.set(CONTROLLER_IN, M_PAPER)
    ctrl.slave.start_continuous_time()
    outside = list(ctrl.slave.current_state())
    outside[0:2], outside[4:12], outside[14:20] = [3.0, -3.0], [1.0] * 8, [-1.0] * 6
    ctrl.slave.set_point(None, outside)
    assert ctrl.slave.update_discrete_states() is True
    state = ctrl.slave.current_state()
    assert state[0:2] == [1.0, -1.0] and state[2:4] == outside[2:4] and state[12:14] == outside[12:14]
    assert ctrl.get1("W1_hat_norm") == pytest.approx(0.5, rel=1e-15)
    assert ctrl.get1("W2_hat_norm") == pytest.approx(0.5, rel=1e-15)
    assert ctrl.slave.update_discrete_states() is False  # in the sets: nothing to move
    other = new("DSCController")
    other.set_state(_through_bytes(ctrl, ctrl.get_state()))
    assert other.slave.model.held == ctrl.slave.model.held and isinstance(other.slave.model.held.projected, tuple)
    assert other.slave.get_derivatives() == ctrl.slave.get_derivatives()


def test_fmu_state_restores_inputs_and_tunable_parameters(new):
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (4.0, 5.0))
    plant.step(0.0, 0.01)
    state = plant.get_state()
    expected = plant.outputs()
    plant.set(("u1", "u2", "max_step"), (-7.0, 9.0, 0.01))
    plant.step(0.01, 0.01)
    plant.set_state(state)
    assert plant.get(("u1", "u2", "max_step")) == [4.0, 5.0, PLANT["max_step"]]
    assert plant.outputs() == expected


# --- refusals and discarded steps ---------------------------------------------------------------

INF, NAN = float("inf"), float("nan")
BAD_VALUES = [
    # (FMU, kind, variable, value): "input" and "tunable" set after a step, "parameter" and "integer" while initialising
    ("MobileRobot", "input", "u1", NAN),
    ("MobileRobot", "input", "u2", INF),
    ("MobileRobot", "input", "u1", -INF),
    ("DSCController", "input", "x", NAN),
    ("DSCController", "input", "theta_dot", -INF),
    ("DSCController", "input", "v_r_dot", INF),
    ("DSCController", "input", "v_r", 0.0),
    ("DSCController", "input", "v_r", -1.0),
    ("MobileRobot", "parameter", "mc", -1.0),
    ("MobileRobot", "parameter", "La1", 0.0),
    ("MobileRobot", "parameter", "max_step", -1.0),
    ("MobileRobot", "parameter", "R", NAN),
    ("MobileRobot", "parameter", "d", -0.1),
    ("DSCController", "parameter", "tau2", 0.0),
    ("DSCController", "parameter", "max_step", -1.0),
    ("DSCController", "parameter", "Gamma1_3", INF),
    ("DSCController", "tunable", "k1", -2.0),
    ("MobileRobot", "tunable", "max_step", 0.0),
    ("ReferenceRobot", "integer", "profile", 7),
    ("ReferenceRobot", "integer", "profile", -1),
    ("ReferenceRobot", "parameter", "vr0", 0.0),
    ("ReferenceRobot", "parameter", "eight_T", -30.0),
]


@pytest.mark.parametrize("name,kind,variable,value", BAD_VALUES,
                         ids=[f"{n}-{k}-{v}={x}" for n, k, v, x in BAD_VALUES])
def test_bad_value_is_refused_named_and_holds_the_slave_until_corrected(name, kind, variable, value):
    """The value is refused with an error naming the variable and its range, the variable keeps its
    last valid value, and every step is discarded (the reason logged) while it is refused; the valid
    value set again lets the steps through, as if the bad one had never been set."""
    integer, inputs, schedule = DRIVES[name]
    inst, twin = InProcess(name, label="bad"), InProcess(name, label="twin")
    get, put = (inst.get_integer, inst.set_integer) if kind == "integer" else (inst.get, inst.set)
    for slave in (inst, twin):
        slave.slave.setup_experiment(0.0)
        slave.slave.enter_initialization_mode()
        if integer and kind != "integer":
            slave.set_integer(list(integer), list(integer.values()))
        if kind in ("input", "tunable"):
            slave.slave.exit_initialization_mode()
            slave.step(0.0, 1e-3)
    before = get([variable])
    put([variable], [value])
    assert get([variable]) == before
    named = re.compile(rf"(?<![\w.]){re.escape(variable)} = ")
    errors = [message for status, message in inst.messages() if status == ERROR]
    assert len(errors) == 1 and named.search(errors[0]) and "allowed" in errors[0], errors
    if kind not in ("input", "tunable"):
        for slave in (inst, twin):
            slave.slave.exit_initialization_mode()
    with pytest.raises(Discarded):
        inst.step(1e-3, 1e-3)
    assert inst.messages()[-1][0] == DISCARD and named.search(inst.messages()[-1][1])
    put([variable], before)
    assert replay(inst, inputs, schedule, 1e-3, 3, 1e-3) == replay(twin, inputs, schedule, 1e-3, 3, 1e-3)


def test_a_refused_input_alone_shows_the_wait_at_once(new):
    """start_on = valid_inputs: outputs read before and after a set of only refused inputs follow the wait."""
    ctrl = new("DSCController", integer={"start_on": VALID_INPUTS})
    assert ctrl.get(("u1", "u2")) != [0.0, 0.0]
    ctrl.set(("v_r",), (0.0,))
    assert ctrl.get(("u1", "u2")) == [0.0, 0.0] and ctrl.outputs()["started"] is False


def test_non_finite_state_discards_the_step_and_keeps_the_slave_usable(new):
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (1e308, 1e308))  # finite and allowed, but u / La overflows the state
    before = plant.get(PLANT_OUT)
    with pytest.raises(Discarded):
        plant.step(0.0, 0.01)
    assert plant.messages()[-1][0] == DISCARD and "not finite" in plant.messages()[-1][1]
    assert plant.get(PLANT_OUT) == before
    plant.set(("u1", "u2"), (5.0, 5.0))
    plant.step(0.0, 0.01)
    assert all(math.isfinite(v) for v in plant.get(PLANT_OUT))


def test_a_step_of_too_many_sub_steps_is_discarded_and_leaves_the_state(new):
    plant = new("MobileRobot", real={"max_step": 1e-3})
    plant.set(("u1", "u2"), (5.0, 5.0))
    before = plant.get(PLANT_OUT)
    with pytest.raises(Discarded):
        plant.step(0.0, (MAX_SUBSTEPS + 1) * 1e-3)
    status, message = plant.messages()[-1]
    assert status == DISCARD
    assert f"needs {MAX_SUBSTEPS + 1} sub-steps" in message and f"at most {MAX_SUBSTEPS}" in message
    assert plant.get(PLANT_OUT) == before
    plant.step(0.0, 1e-3)
    assert plant.get(PLANT_OUT) != before


# --- the beta guard and the wait for valid inputs -----------------------------------------------


def test_beta_guard_is_counted_shown_and_logged_once_while_it_acts(new):
    ctrl = new("DSCController")
    ctrl.set(CONTROLLER_IN, M_GUARD)
    out = ctrl.outputs()
    assert out["beta"] < CONTROLLER["beta_min"] and out["beta_guard_active"] is True
    for k in range(3):
        ctrl.step(k * 1e-3, 1e-3)
    out = ctrl.outputs()
    assert out["beta_guard_count"] == 3
    assert all(math.isfinite(out[n]) for n in ("u1", "u2"))
    warnings = [m for s, m in ctrl.messages() if s == WARNING and "beta" in m]
    assert len(warnings) == 1 and "t = 0 s" in warnings[0]
    ctrl.set(CONTROLLER_IN, M_PAPER)
    assert ctrl.outputs()["beta_guard_active"] is False


def test_start_on_valid_inputs_waits_then_starts_from_the_first_valid_inputs(new):
    """start_on = valid_inputs: all-zero inputs (v_r = 0), as a master without an initial exchange
    gives them, make the controller wait (u = 0, steps accepted, one warning); the first valid
    inputs start it exactly as a controller that saw them first; after that v_r = 0 is refused."""
    h = 1e-3
    ctrl = new("DSCController", integer={"start_on": VALID_INPUTS})
    ctrl.set(CONTROLLER_IN, [0.0] * len(CONTROLLER_IN))
    out = ctrl.outputs()
    assert (out["u1"], out["u2"], out["S11"], out["beta"], out["a1_hat"], out["started"]) == (0, 0, 0, 1, 0, False)
    ctrl.step(0.0, h)
    ctrl.step(h, h)
    assert ctrl.outputs()["started"] is False and ctrl.get(("u1", "u2")) == [0.0, 0.0]
    waits = [m for s, m in ctrl.messages() if s == WARNING and "waits for valid inputs" in m]
    assert len(waits) == 1 and "v_r = 0.0" in waits[0] and "t = 0 s" in waits[0]
    assert not [m for s, m in ctrl.messages() if s >= ERROR]
    ctrl.set(CONTROLLER_IN, M_PAPER)
    g = gains(CONTROLLER)
    law = control_law(g, start_filters(g, initial_controller_state(CONTROLLER), M_PAPER), M_PAPER)
    assert ctrl.get(("u1", "u2")) == [law.u1, law.u2]
    assert ctrl.outputs()["started"] is False
    first = new("DSCController")
    first.set(CONTROLLER_IN, M_PAPER)
    for inst in (ctrl, first):
        inst.step(2 * h, h)
    assert ctrl.outputs()["started"] is True
    assert any("starts after waiting 2 step(s)" in m and "t = 0.002 s" in m for _, m in ctrl.messages())
    assert ctrl.outputs() == first.outputs()
    ctrl.set(("v_r",), (0.0,))
    with pytest.raises(Discarded):
        ctrl.step(3 * h, h)
    assert any(s == ERROR and "v_r = 0.0" in m for s, m in ctrl.messages())


def test_start_on_valid_inputs_does_not_wait_for_a_refused_parameter(new):
    ctrl = new("DSCController", integer={"start_on": VALID_INPUTS})
    ctrl.set(("tau2",), (0.0,))
    ctrl.set(CONTROLLER_IN, [0.0] * len(CONTROLLER_IN))
    with pytest.raises(Discarded):
        ctrl.step(0.0, 1e-3)
    assert any(s == ERROR and "tau2 = 0.0" in m for s, m in ctrl.messages())


# --- the messages -------------------------------------------------------------------------------


@pytest.mark.parametrize("fmi_version", (2, 3))
def test_each_message_has_the_status_and_category_of_its_fmi_version(new, fmi_version):
    """Warning (the guard), error (a refusal) and discard (the step refused): each once, with the FMI
    library's status and the category the library gives that status, naming the instance."""
    ctrl = new("DSCController", fmi_version=fmi_version)
    ctrl.set(CONTROLLER_IN, M_GUARD)
    ctrl.step(0.0, 1e-3)
    ctrl.set(("tau2",), (0.0,))
    with pytest.raises(Discarded):
        ctrl.step(1e-3, 1e-3)
    queue = ctrl.slave.log_queue
    statuses = ctrl.slave.library.status
    assert [(m.status, m.category) for m in queue] == [
        (statuses.warning, "logStatusWarning"), (statuses.error, "logStatusError"),
        (statuses.discard, "logStatusDiscard"),
    ]
    assert all(type(m.status) is statuses and m.msg.startswith(f"{ctrl.name}: ") for m in queue)
