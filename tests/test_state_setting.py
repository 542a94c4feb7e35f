"""Continuous-time states set by value reference in model exchange (fmi2SetReal, fmi3SetFloat64), as
importers such as PyFMI do for their finite-difference Jacobians: in event and continuous-time mode,
equal in effect to setting the same entry of the state vector through fmiSetContinuousStates (FMI
3.0.2, sections 2.3.5 and 3.2.1; FMI 2.0: fmi-standard #392). Outputs that are not states stay refused,
and so does every state outside those modes and in co-simulation. Each check runs the FMU's binary
through fmpy's ctypes API, for the three FMUs, FMI 2.0 and 3.0, against a second instance of the same
FMU that is given the same values through fmiSetContinuousStates.
"""

import math
from pathlib import Path

import pytest
from fmpy import extract
from fmpy.fmi1 import FMICallException

from fmi_ctypes import Fmi2Slave, Fmi3Slave, FmiCallError
from test_model_exchange import CONTROLLER_START, Model, model  # noqa: F401 (fixture)
from dsc_fmu.registry import FMUS

NAMES = tuple(FMUS)


def _ready(make, name: str, mode: str) -> Model:
    """An instance of ``name`` made by ``make`` (the fixture ``model``), its inputs set away from their start
    values, in ``mode`` ("event" or "continuous")."""
    instance = make(name)
    inputs = {v.name: CONTROLLER_START.get(v.name, 1.0) + 0.3 for v in FMUS[name].inputs}
    if inputs:
        instance.set(inputs)
    instance.fmu.exitInitializationMode()
    while instance.loaded.update_discrete_states()[0]:
        pass
    if mode == "continuous":
        instance.fmu.enterContinuousTimeMode()
    return instance


def _states(name: str) -> list[str]:
    return [s.variable.name for s in FMUS[name].states]


def _evaluation(instance: Model) -> list[str]:
    """What the next evaluation gives, bit by bit: states, derivatives, event indicators, the outputs."""
    outputs = [v.name for v in FMUS[instance.fmu.instanceName].outputs]
    values = [*instance.vector("getContinuousStates"), *instance.derivatives(),
              *instance.vector("getEventIndicators", instance.nz), *instance.get(outputs).values()]
    return [value.hex() for value in values]


def _moved(x: list[float], i: int) -> float:
    """A new value for the state ``x[i]``, away from it by a quarter and a tenth."""
    return 1.25 * x[i] + 0.1


def _set_function(instance: Model) -> str:
    return "fmi2SetReal" if instance.version == 2 else "fmi3SetFloat64"


@pytest.mark.parametrize("mode", ("event", "continuous"))
@pytest.mark.parametrize("name", NAMES)
def test_each_state_set_by_value_reference_is_that_entry_of_the_state_vector(model, name, mode):
    """Each state in turn, by value reference: fmiGetContinuousStates returns it, and the derivatives, event
    indicators and outputs are bit for bit those of an instance given the same vector by
    fmiSetContinuousStates."""
    by_reference, by_vector = _ready(model, name, mode), _ready(model, name, "continuous")
    x = by_reference.vector("getContinuousStates")
    assert _evaluation(by_reference) == _evaluation(by_vector)
    for i, state in enumerate(_states(name)):
        x[i] = _moved(x, i)
        by_reference.set({state: x[i]})
        by_vector.states(x)
        assert by_reference.vector("getContinuousStates") == x
        assert _evaluation(by_reference) == _evaluation(by_vector), state
    by_reference.close()
    by_vector.close()


@pytest.mark.parametrize("name", NAMES)
def test_states_and_inputs_set_in_one_call_are_set_both(model, name):
    """One fmiSetReal with the states and the inputs interleaved equals the inputs set by value reference
    and the states by fmiSetContinuousStates."""
    by_reference, by_vector = _ready(model, name, "continuous"), _ready(model, name, "continuous")
    x = by_reference.vector("getContinuousStates")
    x = [_moved(x, i) for i in range(len(x))]
    inputs = {v.name: CONTROLLER_START.get(v.name, 1.0) - 0.2 for v in FMUS[name].inputs}
    mixed = {}
    for i, state in enumerate(_states(name)):
        mixed[state] = x[i]
        mixed.update(list(inputs.items())[i:i + 1])
    assert len(mixed) == len(x) + len(inputs)
    by_reference.set(mixed)
    if inputs:
        by_vector.set(inputs)
    by_vector.states(x)
    assert _evaluation(by_reference) == _evaluation(by_vector)
    by_reference.close()
    by_vector.close()


@pytest.mark.parametrize("name", NAMES)
def test_a_finite_difference_jacobian_by_value_reference_is_the_one_by_the_state_vector(model, name):
    """The Jacobian's columns as PyFMI forms them (state i set to x_i + d by value reference, the
    derivatives read, state i set back) equal those formed through fmiSetContinuousStates, and the
    derivatives after each column are the ones before it."""
    by_reference, by_vector = _ready(model, name, "continuous"), _ready(model, name, "continuous")
    for instance in (by_reference, by_vector):
        instance.fmu.setTime(0.2)
    x = by_reference.vector("getContinuousStates")
    base = by_reference.derivatives()
    columns = []
    for i, state in enumerate(_states(name)):
        d = 1.5e-8 * max(abs(x[i]), 1.0)
        by_reference.set({state: x[i] + d})
        column = [(after - before) / d for after, before in zip(by_reference.derivatives(), base)]
        by_reference.set({state: x[i]})
        by_vector.states([*x[:i], x[i] + d, *x[i + 1:]])
        expected = [(after - before) / d for after, before in zip(by_vector.derivatives(), base)]
        by_vector.states(x)
        assert [v.hex() for v in column] == [v.hex() for v in expected], state
        assert by_reference.derivatives() == base
        columns.append(column)
    assert any(any(column) for column in columns)
    by_reference.close()
    by_vector.close()


def _non_state_output(name: str) -> str:
    states = set(_states(name))
    return next(v.name for v in FMUS[name].outputs if v.name not in states)


@pytest.mark.parametrize("name", NAMES)
def test_an_output_that_is_not_a_state_is_still_refused_and_nothing_is_set(model, name):
    """A set that includes an output that is not a state, or a state's derivative, is fmiError with the
    message it always had, and the states before it in the call keep their values."""
    for target, reason in ((_non_state_output(name), "is an output: it cannot be set"),
                           (FMUS[name].states[0].derivative.name, "cannot be set")):
        instance = _ready(model, name, "continuous")
        x = instance.vector("getContinuousStates")
        with pytest.raises(FMICallException, match="status 3"):
            instance.set({_states(name)[0]: _moved(x, 0), target: 1.0})
        refused = f"{_set_function(instance)}: value reference {instance.refs[target]} {reason}"
        assert any(m.message.endswith(refused) for m in instance.log), instance.log
        assert instance.vector("getContinuousStates") == x
        instance.free()


@pytest.mark.parametrize("mode", ("event", "continuous"))
def test_a_state_that_is_not_finite_is_discarded_with_the_rest_of_the_call(model, mode):
    """As fmiSetContinuousStates: NaN or infinity for a state is fmiDiscard, nothing of the call is set (an
    input beside it neither), and the instance goes on."""
    instance = _ready(model, "DSCController", mode)
    before = _evaluation(instance)
    for bad in (math.nan, math.inf):
        with pytest.raises(FMICallException, match="status 2"):
            instance.set({"i1": 2.5, "a1_hat": bad})
        refused = f"value reference {instance.refs['a1_hat']}, a continuous state, is {bad}; allowed: finite"
        assert any(refused in m.message and m.status in ("DISCARD", "2") for m in instance.log), instance.log
        assert _evaluation(instance) == before
    instance.set({"a1_hat": 3.0})
    assert instance.vector("getContinuousStates")[0] == 3.0
    instance.close()


@pytest.mark.parametrize("version", (2, 3))
def test_outside_event_and_continuous_time_mode_a_state_is_not_set_by_value_reference(fmu_paths, fmu3_paths, tmp_path,
                                                                                      version):
    """In initialization mode of model exchange (its states are calculated there) and in co-simulation,
    where nothing changes: a state is an output that cannot be set."""
    paths = fmu_paths if version == 2 else fmu3_paths
    for interface in ("model exchange", "co-simulation"):
        folder = Path(extract(str(paths["MobileRobot"]), unzipdir=tmp_path / interface.replace(' ', '_')))
        fmu = (Fmi2Slave if version == 2 else Fmi3Slave)(folder, "plant")
        fmu.instantiate(model_exchange=interface == "model exchange")
        if version == 2:
            fmu.setup_experiment()
        fmu.enter_initialization_mode()
        if interface == "co-simulation":
            fmu.exit_initialization_mode()
        with pytest.raises(FmiCallError):
            (fmu.set_real if version == 2 else fmu.set_float64)(["x"], [3.0])
        assert f"value reference {fmu.variables['x'][0]} is an output: it cannot be set" in fmu.messages[-1][-1]
        fmu.free_instance()
