"""The binary's partial derivatives (``dsc_fmu/fmubuild/native``): ``fmi2GetDirectionalDerivative`` (model
exchange and co-simulation), ``fmi3GetDirectionalDerivative`` and ``fmi3GetAdjointDerivative``.

The states each is allowed in are walked with every other function in ``test_fmi_states.py``. Here: the
arguments the C layer checks before Python sees them (the FMI 3.0 counts, NULL arrays with a nonzero
count, value references of no Real variable), the lists it hands to the slave and the answer it copies
out, and a failure of the slave: one error message and fmiError, the instance in the standard's error
state, never a crash. Where the values matter, a recording stand-in takes the place of the slave's
``directional_derivative`` and ``adjoint_derivative`` (``ModelSlave``), so that these are tests of the C
layer alone; the derivatives themselves are checked against finite differences elsewhere.
"""

import sys
import zipfile
from ctypes import c_double, c_size_t, c_uint, c_void_p
from pathlib import Path

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Model, FMU2Slave
from fmpy.fmi3 import FMU3Model, FMU3Slave
from fmpy.validation import validate_fmu

from test_fmi_states import Walk
from dsc_fmu.fmubuild.fmus import build_fmu
from dsc_fmu.registry import FMUS

ERROR = 3
NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
FLAGS = {2: {"providesDirectionalDerivative": "true"},
         3: {"providesDirectionalDerivatives": "true", "providesAdjointDerivatives": "true"}}


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    """MobileRobot (states, inputs and outputs), FMI 2.0 and 3.0, extracted: version -> folder. Built without the
    traced C (``--no-traced``): the binary asks the slave's methods, which the tests stand in for."""
    root = tmp_path_factory.mktemp("partials")
    return {version: Path(extract(str(build_fmu(FMUS["MobileRobot"], root / f"built{version}", version, traced=False)),
                                  unzipdir=root / f"fmi{version}")) for version in (2, 3)}


class Recorder:
    """Stands in for ``ModelSlave.directional_derivative`` / ``adjoint_derivative``: records each call's
    arguments and answers ``answer(unknowns, knowns, seed)``."""

    def __init__(self, answer):
        self.calls, self.answer = [], answer

    def method(self):
        recorder = self

        def partials(slave, unknowns, knowns, seed, model_exchange):
            recorder.calls.append((unknowns, knowns, seed, model_exchange))
            return recorder.answer(unknowns, knowns, seed)

        return partials


def model_slave(folder: Path):
    """The class ``ModelSlave`` that the binary of the extracted FMU in ``folder`` loaded into this process."""
    resources = (folder / "resources").resolve()
    for name, module in list(sys.modules.items()):
        file = getattr(module, "__file__", None)
        if name.endswith(".fmu.slave") and file and resources in Path(file).resolve().parents:
            return module.ModelSlave
    raise AssertionError(f"no slave module of {folder} is loaded")


def stand_in(monkeypatch, folder: Path, answer) -> Recorder:
    """Both partial-derivative methods of the FMU in ``folder`` replaced by one ``Recorder``."""
    recorder = Recorder(answer)
    slave = model_slave(folder)
    for method in ("directional_derivative", "adjoint_derivative"):
        monkeypatch.setattr(slave, method, recorder.method(), raising=False)
    return recorder


def refs(*values):
    return (c_uint * len(values))(*values)


def doubles(*values):
    return (c_double * len(values))(*values)


def errors(walk: Walk) -> list[str]:
    status = 0 if walk.version == 3 else 1
    return [m[-1] for m in walk.fmu.messages if m[status] == ERROR]


def vr(walk: Walk, *names) -> list[int]:
    return [walk.fmu.variables[name][0] for name in names]


# --- the model descriptions ----------------------------------------------------------------------------------

@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_every_fmu_declares_its_partial_derivatives_in_both_interfaces(fmu_paths, fmu3_paths, name, version):
    """FMI 2.0 ``providesDirectionalDerivative``, FMI 3.0 ``providesDirectionalDerivatives`` and
    ``providesAdjointDerivatives``, on ModelExchange and CoSimulation; the FMU still validates."""
    path = (fmu3_paths if version == 3 else fmu_paths)[name]
    with zipfile.ZipFile(path) as fmu:
        from xml.etree import ElementTree

        root = ElementTree.fromstring(fmu.read("modelDescription.xml"))
    for tag in ("ModelExchange", "CoSimulation"):
        assert {k: root.find(tag).get(k) for k in FLAGS[version]} == FLAGS[version], tag
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    for interface in (md.modelExchange, md.coSimulation):
        # fmpy 0.3 reads FMI 3.0's flag under FMI 2.0's name (providesDirectionalDerivative), which FMI 3.0
        # does not have: the XML above is the check of it.
        assert (interface.providesAdjointDerivatives if version == 3 else interface.providesDirectionalDerivative)


# --- arguments refused before Python sees them ---------------------------------------------------------------

@pytest.mark.parametrize("adjoint", (False, True), ids=("directional", "adjoint"))
@pytest.mark.parametrize("model_exchange", (False, True), ids=("co-simulation", "model-exchange"))
def test_fmi3_counts_that_do_not_match_are_refused(plant, monkeypatch, model_exchange, adjoint):
    """FMI 3.0: every variable is a scalar, so nSeed is nKnowns (adjoint: nUnknowns) and nSensitivity is
    nUnknowns (adjoint: nKnowns); anything else is fmi3Error naming both counts, the slave not called."""
    function = "fmi3GetAdjointDerivative" if adjoint else "fmi3GetDirectionalDerivative"
    seeded, sensed = ("nUnknowns", "nKnowns") if adjoint else ("nKnowns", "nUnknowns")
    cases = [(3, 2, f"nSeed is 3 but {seeded} is 2; allowed: nSeed = {seeded} (every variable is a scalar)"),
             (2, 0, f"nSensitivity is 0 but {sensed} is 2; allowed: nSensitivity = {sensed}")]
    for n_seed, n_sensitivity, message in cases:
        walk = Walk(plant[3], 3, "C" if model_exchange else "S", model_exchange=model_exchange)
        recorder = stand_in(monkeypatch, plant[3], lambda u, k, s: [0.0] * len(u))
        unknowns, knowns = vr(walk, "x", "y"), vr(walk, "u1", "u2")
        status = walk.raw(function, refs(*unknowns), c_size_t(2), refs(*knowns), c_size_t(2),
                          doubles(1, 0, 0), c_size_t(n_seed), doubles(0, 0, 0), c_size_t(n_sensitivity))
        failures = errors(walk)
        assert status == ERROR and walk.in_error_state()
        assert [m for m in failures if f"{function}: " in m and message in m], walk.messages()
        assert recorder.calls == []
        walk.close()


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("missing", ("unknowns", "knowns", "seed values", "sensitivity values"))
def test_a_null_array_with_a_nonzero_count_is_refused(plant, monkeypatch, version, missing):
    """Each of the four arrays NULL while its count is not zero: fmiError with one message naming it."""
    walk = Walk(plant[version], version, "C", model_exchange=True)
    recorder = stand_in(monkeypatch, plant[version], lambda u, k, s: [0.0] * len(u))
    unknowns, knowns = refs(*vr(walk, "x", "y")), refs(*vr(walk, "u1", "u2"))
    seed, sensitivity = doubles(1, 0), doubles(0, 0)
    arrays = {"unknowns": unknowns, "knowns": knowns, "seed values": seed, "sensitivity values": sensitivity}
    arrays[missing] = c_void_p()
    two = c_size_t(2)
    if version == 2:
        status = walk.raw("fmi2GetDirectionalDerivative", arrays["unknowns"], two, arrays["knowns"], two,
                          arrays["seed values"], arrays["sensitivity values"])
    else:
        status = walk.raw("fmi3GetDirectionalDerivative", arrays["unknowns"], two, arrays["knowns"], two,
                          arrays["seed values"], two, arrays["sensitivity values"], two)
    failures = errors(walk)
    assert status == ERROR and walk.in_error_state()
    function = f"fmi{version}GetDirectionalDerivative"
    assert failures[0].endswith(f"{function}: 2 {missing} but no array of them (NULL)"), walk.messages()
    assert recorder.calls == []
    walk.close()


@pytest.mark.parametrize("version", (2, 3))
def test_value_references_of_no_real_variable_are_refused_in_c(plant, monkeypatch, version):
    """A value reference of no variable, or of an Integer / Int32 one: refused as fmiGetReal refuses them."""
    for unknown, message in ((99999, "value reference 99999 is not a variable of this FMU"),
                             ("coupling", "is a {} variable, not {}")):
        walk = Walk(plant[version], version, "C", model_exchange=True)
        recorder = stand_in(monkeypatch, plant[version], lambda u, k, s: [0.0] * len(u))
        reference = unknown if isinstance(unknown, int) else vr(walk, unknown)[0]
        kind = ("Integer" if version == 2 else "Int32") if not isinstance(unknown, int) else None
        status = walk.raw(f"fmi{version}GetDirectionalDerivative", refs(reference), c_size_t(1),
                          refs(*vr(walk, "u1")), c_size_t(1), doubles(1.0),
                          *((doubles(0.0),) if version == 2 else (c_size_t(1), doubles(0.0), c_size_t(1))))
        failures = errors(walk)
        assert status == ERROR and walk.in_error_state()
        text = message if kind is None else message.format(kind, "Real" if version == 2 else "Float64")
        assert len(failures) == 1 and text in failures[0], walk.messages()
        assert recorder.calls == []
        walk.close()


@pytest.mark.parametrize("version", (2, 3))
def test_no_unknowns_and_no_knowns_is_ok_without_python(plant, monkeypatch, version):
    walk = Walk(plant[version], version, "C", model_exchange=True)
    recorder = stand_in(monkeypatch, plant[version], lambda u, k, s: [])
    none, zero = c_void_p(), c_size_t(0)
    if version == 2:
        assert walk.raw("fmi2GetDirectionalDerivative", none, zero, none, zero, none, none) == 0
    else:
        for function in ("fmi3GetDirectionalDerivative", "fmi3GetAdjointDerivative"):
            assert walk.raw(function, none, zero, none, zero, none, zero, none, zero) == 0
    assert recorder.calls == [] and errors(walk) == []
    walk.close()


# --- what goes to the slave and comes back -------------------------------------------------------------------

def fmpy_instance(folder: Path, version: int, model_exchange: bool, messages: list):
    """The MobileRobot in ``folder`` through fmpy's ctypes API, initialised: model exchange in
    continuous-time mode, co-simulation in step mode; its messages appended to ``messages``."""
    md = read_model_description(str(folder))
    interface = md.modelExchange if model_exchange else md.coSimulation
    kinds = {(2, True): FMU2Model, (2, False): FMU2Slave, (3, True): FMU3Model, (3, False): FMU3Slave}
    fmu = kinds[version, model_exchange](guid=md.guid if version == 2 else md.instantiationToken,
                                         unzipDirectory=str(folder), modelIdentifier=interface.modelIdentifier,
                                         instanceName="partials")
    if version == 2:
        from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

        def log(environment, instance, status, category, message):
            messages.append((status, message.decode()))

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(log)
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    else:
        def log(environment, status, category, message):
            messages.append((status, message.decode()))

        fmu.instantiate(loggingOn=True, logMessage=log)
        fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    if model_exchange:
        fmu.enterContinuousTimeMode()
    fmu.references = {v.name: v.valueReference for v in md.modelVariables}
    return fmu


@pytest.mark.parametrize("model_exchange", (False, True), ids=("co-simulation", "model-exchange"))
@pytest.mark.parametrize("version", (2, 3))
def test_the_slave_gets_plain_lists_and_its_answer_comes_back_in_order(plant, monkeypatch, version,
                                                                       model_exchange):
    """fmpy's getDirectionalDerivative (and FMI 3.0's getAdjointDerivative): the slave's method gets the
    value references as ints, the seed as floats, the interface as a bool; its floats come back in the
    order of the unknowns (the knowns for the adjoint)."""
    answer = lambda unknowns, knowns, seed: [1000.0 * r + sum(seed) for r in unknowns]  # noqa: E731
    messages = []
    fmu = fmpy_instance(plant[version], version, model_exchange, messages)
    recorder = stand_in(monkeypatch, plant[version], answer)
    r = fmu.references
    unknowns, knowns, seed = [r["x"], r["theta"], r["y"]], [r["u2"], r["u1"]], [0.25, -2.0]
    assert fmu.getDirectionalDerivative(unknowns, knowns, seed) == answer(unknowns, knowns, seed)
    assert recorder.calls == [(unknowns, knowns, seed, model_exchange)]
    assert all(type(v) is int for v in unknowns + knowns) and all(type(v) is float for v in recorder.calls[0][2])
    if version == 3:
        adjoint_seed = [1.0, 0.5, -1.0]
        expected = [1000.0 * k + 0.5 for k in knowns]
        recorder.answer = lambda unknowns, knowns, seed: [1000.0 * k + sum(seed) for k in knowns]
        assert fmu.getAdjointDerivative(unknowns, knowns, adjoint_seed, nSensitivity=len(knowns)) == expected
        assert recorder.calls[-1] == (unknowns, knowns, adjoint_seed, model_exchange)
    assert [m for m in messages if m[0] == ERROR] == []
    fmu.terminate()
    fmu.freeInstance()


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("answer,message", [
    (lambda u, k, s: [0.0], "directional_derivative returned 1 values; expected 2"),
    (lambda u, k, s: ["a", "b"], "directional_derivative failed: TypeError: must be real number, not str"),
    (lambda u, k, s: None, "directional_derivative failed: TypeError: object of type 'NoneType' has no len()"),
    (lambda u, k, s: 1 / 0, "directional_derivative failed: ZeroDivisionError: division by zero"),
], ids=("length", "not-numbers", "none", "raises"))
def test_a_failing_slave_is_one_error_message_and_fmi_error(plant, monkeypatch, version, answer, message):
    """Whatever the slave returns or raises: fmiError, exactly one error message, the error state."""
    walk = Walk(plant[version], version, "C", model_exchange=True)
    stand_in(monkeypatch, plant[version], answer)
    unknowns, knowns = refs(*vr(walk, "x", "y")), refs(*vr(walk, "u1"))
    sensitivity = doubles(0.0, 0.0)
    counts = () if version == 2 else (c_size_t(1),)
    status = walk.raw(f"fmi{version}GetDirectionalDerivative", unknowns, c_size_t(2), knowns, c_size_t(1),
                      doubles(1.0), *counts, sensitivity, *((c_size_t(2),) if version == 3 else ()))
    failures = errors(walk)
    assert status == ERROR and walk.in_error_state()
    assert len(failures) == 1 and message in failures[0], walk.messages()
    walk.close()


@pytest.mark.parametrize("model_exchange", (False, True), ids=("co-simulation", "model-exchange"))
@pytest.mark.parametrize("version", (2, 3))
def test_a_reference_the_slave_refuses_is_one_error_and_no_crash(plant, version, model_exchange):
    """The FMU's own methods: an input asked for as an unknown is refused by the slave (its ValueError
    naming the reference and what is allowed), one error message, fmiError, and the instance lives on
    through fmiReset."""
    state = "C" if model_exchange else "S"
    walk = Walk(plant[version], version, state, model_exchange=model_exchange)
    counts = () if version == 2 else (c_size_t(1),)
    status = walk.raw(f"fmi{version}GetDirectionalDerivative", refs(*vr(walk, "u1")), c_size_t(1),
                      refs(*vr(walk, "u2")), c_size_t(1), doubles(1.0), *counts, doubles(0.0), *counts)
    failures = errors(walk)
    assert status == ERROR and walk.in_error_state()
    assert len(failures) == 1 and "directional_derivative failed: ValueError: value reference" in failures[0], \
        walk.messages()
    kind = "Real" if version == 2 else "Float64"
    assert f"(u1) is a {kind} input, not an unknown" in failures[0] and "allowed unknowns:" in failures[0], failures
    assert walk.raw(f"fmi{version}Reset") == 0
    walk.enter(state)
    assert walk.raw(f"fmi{version}GetDirectionalDerivative", c_void_p(), c_size_t(0), c_void_p(), c_size_t(0),
                    c_void_p(), *(() if version == 2 else (c_size_t(0),)), c_void_p(),
                    *(() if version == 2 else (c_size_t(0),))) == 0
    walk.close()


# --- one Jacobian column in a C host without Python, against finite differences -----------------------------

def fmpy_model_exchange(folder: Path, md, version: int):
    """The FMU in ``folder`` through fmpy, initialised (inputs at their start values) and in continuous-time
    mode."""
    kind = FMU3Model if version == 3 else FMU2Model
    fmu = kind(guid=md.guid if version == 2 else md.instantiationToken, unzipDirectory=str(folder),
               modelIdentifier=md.modelExchange.modelIdentifier, instanceName="differences")
    fmu.instantiate()
    if version == 3:
        fmu.enterInitializationMode(startTime=0.0)
    else:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.enterContinuousTimeMode()
    return fmu


def central_differences(fmu, version: int, time: float, states: list, known: int, unknowns: list) -> list:
    """d unknowns / d known at ``time`` and the continuous ``states`` (inputs held), by the five-point
    central difference of the FMU's own values (error O(h⁴))."""
    get, put = (fmu.getFloat64, fmu.setFloat64) if version == 3 else (fmu.getReal, fmu.setReal)
    fmu.setTime(time)
    fmu.setContinuousStates((c_double * len(states))(*states), len(states))
    centre = get([known])[0]
    h = 1e-3 * max(abs(centre), 1e-3)  # near the best step of the five-point rule (eps ** 0.2), at the value's scale
    values = {}
    for k in (-2, -1, 1, 2):
        put([known], [centre + k * h])
        values[k] = get(unknowns)
    put([known], [centre])
    return [(values[-2][i] - 8 * values[-1][i] + 8 * values[1][i] - values[2][i]) / (12 * h)
            for i in range(len(unknowns))]


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_jacobian_columns_from_a_c_host_equal_finite_differences(fmu_paths, fmu3_paths, tmp_path, name, version):
    """``c_model_exchange`` from an empty environment, JACOBIAN set: after 50 RK4 steps of 0.02 s, the
    column of every state and input (fmiGetDirectionalDerivative; FMI 3.0 also each entry from
    fmi3GetAdjointDerivative) against the five-point central differences of the FMU's derivatives and
    outputs at the states the host printed, to 1e-8 of the column's largest entry."""
    from c_hosts import EMPTY_ENVIRONMENT, compile_c, parse_rows, run_c

    host = compile_c("c_model_exchange.c", tmp_path / "c_model_exchange")
    path = (fmu3_paths if version == 3 else fmu_paths)[name]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / name))
    states = [d.variable.derivative.valueReference for d in md.derivatives]
    inputs = [v.valueReference for v in md.modelVariables if v.causality == "input" and v.type in ("Real", "Float64")]
    unknowns = [d.variable.valueReference for d in md.derivatives] + [
        v.valueReference for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Float64")]
    token = md.guid if version == 2 else md.instantiationToken
    steps, step = 50, 0.02
    fmu = fmpy_model_exchange(folder, md, version)
    for known in states + inputs:
        env = {**EMPTY_ENVIRONMENT, "JACOBIAN": f"{known}:{','.join(map(str, unknowns))}"}
        run = run_c([host, version, folder, md.modelExchange.modelIdentifier, token, len(states),
                     md.numberOfEventIndicators, steps, step, *unknowns[:1]], tmp_path, env)
        assert run.returncode == 0, run.stderr
        lines = {line.split(",")[0]: parse_rows(line.split(",", 1)[1])[0] for line in run.stdout.splitlines()
                 if line.startswith(("states,", "jacobian,", "adjoint,"))}
        expected = central_differences(fmu, version, steps * step, lines["states"], known, unknowns)
        scale = max(1.0, *map(abs, expected))
        assert lines["jacobian"] == pytest.approx(expected, rel=1e-8, abs=1e-8 * scale), known
        if version == 3:
            assert lines["adjoint"] == pytest.approx(lines["jacobian"], rel=1e-14, abs=1e-14 * scale)
    fmu.terminate()
    fmu.freeInstance()
