"""The three FMUs through fmpy: model descriptions, and what only the binary does with the slaves.

What the binary adds to a slave: the importer's logger, fmi2DoStep's statuses and the state after a
discarded step, FMU states serialized through ctypes, a Python exception turned into a discarded step,
the FMUs' modules in one process. What the slaves decide and compute is tested in this process
(test_slave_behaviour.py, test_slave_physics.py). Expectations come from the variable tables
(dsc_fmu.models.parameters), the FMI 2.0 standard, the interface names of the issue and the models;
never from numbers copied from the FMUs' own output.
"""

import gc
import itertools
import math
import re
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import pytest
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.validation import validate_fmu

from dsc_fmu.identity import fmu_build_id
from dsc_fmu.registry import FMUS
from dsc_fmu.models import parameters as P
from drives import CONTROLLER_IN, DRIVES, M_GUARD, M_PAPER, NAMES, PLANT_OUT, replay

FMI2_OK, FMI2_WARNING, FMI2_DISCARD, FMI2_ERROR, FMI2_FATAL = range(5)

# --- the interface of the issue (part of the product) -------------------------------------------

EXPECTED = {
    "MobileRobot": {
        "parameter": (
            "R", "d", "r", "mc", "mw", "Ic", "Iw", "Im", "d11", "d22", "Ra1", "Ra2", "La1", "La2",
            "KE1", "KE2", "KT1", "KT2", "N1", "N2", "x0", "y0", "theta0",
            "omega1_0", "omega2_0", "i1_0", "i2_0", "coupling", "voltage_limit", "u_max1", "u_max2",
            "tau_dc1", "tau_dc2", "tau_da1", "tau_da2", "f_d1", "f_d2", "phi_d1", "phi_d2", "max_step", "traced",
        ),
        "input": ("u1", "u2"),
        "output": ("x", "y", "theta", "theta_dot", "omega1", "omega2", "i1", "i2", "u1_applied", "u2_applied",
                   "saturation_time", "saturation_count", "saturation_active"),
    },
    "ReferenceRobot": {
        "parameter": ("x0", "y0", "theta0", "profile", "vr0", "wr0", "eight_A", "eight_B", "eight_T", "max_step",
                      "traced"),
        "input": (),
        "output": ("x_r", "y_r", "theta_r", "v_r", "omega_r", "v_r_dot"),
    },
    "DSCController": {
        "parameter": (
            "k1", "k2", "k3", "k4", "k5", "gamma1", "gamma2", "sigma1", "sigma2", "sigma3", "sigma4",
            "tau2", "tau3", *(f"Gamma1_{i}" for i in range(1, 9)), *(f"Gamma2_{i}" for i in range(1, 7)),
            "a1_hat0", "a2_hat0", *(f"W1_hat0_{i}" for i in range(1, 9)), *(f"W2_hat0_{i}" for i in range(1, 7)),
            "discretization", "start_on", "coupling", "beta_min", "adaptation", "a1_min", "a1_max", "a2_min",
            "a2_max", "W1_max", "W2_max", "max_step", "traced",
        ),
        "input": (
            "x", "y", "theta", "theta_dot", "omega1", "omega2", "i1", "i2",
            "x_r", "y_r", "theta_r", "v_r", "omega_r", "v_r_dot",
        ),
        "output": (
            "u1", "u2", "S11", "S12", "S13", "a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm",
            *(f"W1_hat_{i}" for i in range(1, 9)), *(f"W2_hat_{i}" for i in range(1, 7)),
            "beta", "beta_guard_count", "beta_guard_active", "projection_active", "started",
        ),
    },
}

TABLES = {
    "ReferenceRobot": {"parameter": P.REFERENCE_PARAMETERS, "input": (), "output": P.REFERENCE_OUTPUTS},
    "MobileRobot": {"parameter": P.PLANT_PARAMETERS, "input": P.PLANT_INPUTS,
                    "output": (*P.PLANT_OUTPUTS, *P.DRIVE_OUTPUTS)},
    "DSCController": {
        "parameter": P.CONTROLLER_PARAMETERS, "input": P.CONTROLLER_INPUTS, "output": P.CONTROLLER_OUTPUTS,
    },
}
# Outputs registered outside the tables (docs/model.md §5: the beta guard and the drivers' limit made visible), with
# their FMI type.
EXTRA_OUTPUTS = {"DSCController": {"beta_guard_count": "Integer", "beta_guard_active": "Boolean",
                                   "projection_active": "Boolean", "started": "Boolean"},
                 "MobileRobot": {"saturation_count": "Integer", "saturation_active": "Boolean"}}

REFERENCE_OUT = tuple(v.name for v in P.REFERENCE_OUTPUTS)


# --- logging and instances ----------------------------------------------------------------------


class FmiLog:
    """fmi2CallbackFunctions whose logger records (instance, status, category, message).

    No fmpy logger proxy: it is one slot per process, left dangling by whoever registered last
    (pythonfmu's messages need no formatting). One object for the whole module: the FMUs keep a
    pointer to the struct.
    """

    def __init__(self):
        self.records = []
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)

    def _log(self, environment, instance, status, category, message):
        decode = lambda b: "" if b is None else b.decode("utf-8", "replace")  # noqa: E731
        self.records.append((decode(instance), status, decode(category), decode(message)))

    def of(self, instance):
        return [(status, message) for name, status, _, message in self.records if name == instance]


LOG = FmiLog()
_serial = itertools.count()


class Instance:
    """An fmpy FMU2Slave with value references by name and logging into ``LOG``."""

    def __init__(self, md, unzipped, label=""):
        self.md = md
        self.name = f"{md.coSimulation.modelIdentifier}_{label}{next(_serial)}"
        self.fmu = FMU2Slave(
            guid=md.guid, unzipDirectory=str(unzipped),
            modelIdentifier=md.coSimulation.modelIdentifier, instanceName=self.name,
        )
        self.fmu.instantiate(callbacks=LOG.callbacks, loggingOn=True)
        self.variables = {v.name: v for v in md.modelVariables}
        self.vr = {name: v.valueReference for name, v in self.variables.items()}

    def initialize(self, real=None, integer=None, start_time=0.0):
        self.fmu.setupExperiment(startTime=start_time)
        self.fmu.enterInitializationMode()
        for name, value in (real or {}).items():
            self.fmu.setReal([self.vr[name]], [value])
        for name, value in (integer or {}).items():
            self.fmu.setInteger([self.vr[name]], [value])
        self.fmu.exitInitializationMode()
        return self

    def set(self, names, values):
        self.fmu.setReal([self.vr[n] for n in names], list(values))

    def get(self, names):
        return self.fmu.getReal([self.vr[n] for n in names])

    def get1(self, name):
        return self.get([name])[0]

    def outputs(self) -> dict:
        """Every output by name, read with the getter of its type."""
        result = {}
        for kind, getter, cast in (("Real", self.fmu.getReal, float), ("Integer", self.fmu.getInteger, int),
                                   ("Boolean", self.fmu.getBoolean, bool)):
            names = [n for n, v in self.variables.items() if v.causality == "output" and v.type == kind]
            if names:
                result.update(zip(names, map(cast, getter([self.vr[n] for n in names]))))
        return result

    def step(self, t, h):
        self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)

    def messages(self):
        return LOG.of(self.name)

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


@pytest.fixture(scope="module")
def md(fmu_paths):
    return {name: read_model_description(str(path)) for name, path in fmu_paths.items()}


@pytest.fixture()
def new(md, fmu_unzipped):
    """Factory of initialized instances; closes those still open at the end of the test."""
    opened = []

    def make(name, real=None, integer=None, label=""):
        instance = Instance(md[name], fmu_unzipped[name], label)
        opened.append(instance)
        return instance.initialize(real, integer)

    yield make
    for instance in opened:  # freed in whatever state the test left it (an error state cannot terminate)
        if not getattr(instance, "abandoned", False) and instance.fmu.component is not None:
            instance.fmu.freeInstance()


def scalar(md, name):
    return {v.name: v for v in md.modelVariables}[name]


# --- model descriptions -------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_validate_fmu_reports_no_problems(fmu_paths, name):
    assert validate_fmu(str(fmu_paths[name])) == []


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("causality", ("parameter", "input", "output"))
def test_interface_names_are_the_products(md, name, causality):
    declared = [v.name for v in md[name].modelVariables if v.causality == causality]
    assert sorted(declared) == sorted(EXPECTED[name][causality])
    table = [v.name for v in TABLES[name][causality]]
    if causality == "output":
        table += list(EXTRA_OUTPUTS.get(name, {}))
    assert sorted(declared) == sorted(table)
    assert len(set(declared)) == len(declared)


@pytest.mark.parametrize("name", NAMES)
def test_no_variables_beyond_the_interface_and_model_exchange(md, name):
    """The locals are the states that are not outputs, the states' derivatives and the event indicators."""
    assert {v.causality for v in md[name].modelVariables} <= {"parameter", "input", "output", "local"}
    assert [v.name for v in md[name].modelVariables if v.causality == "local"] == [v.name for v in FMUS[name].locals]


@pytest.mark.parametrize("name", NAMES)
def test_types_and_variability_follow_the_tables(md, name):
    variables = {v.name: v for v in md[name].modelVariables}
    problems = []
    for v in TABLES[name]["parameter"]:
        sv = variables[v.name]
        want = ("Integer" if v.integer else "Real", "tunable" if v.tunable else "fixed")
        if (sv.type, sv.variability) != want:
            problems.append((v.name, sv.type, sv.variability, want))
    for causality in ("input", "output"):
        for v in TABLES[name][causality]:
            sv = variables[v.name]
            if (sv.type, sv.variability) != ("Real", "continuous"):
                problems.append((v.name, sv.type, sv.variability))
    for extra, kind in EXTRA_OUTPUTS.get(name, {}).items():
        sv = variables[extra]
        if (sv.type, sv.variability) != (kind, "discrete"):
            problems.append((extra, sv.type, sv.variability))
    assert problems == []


@pytest.mark.parametrize("name, variable, choices", [
    ("ReferenceRobot", "profile", P.PROFILES), ("DSCController", "discretization", P.DISCRETIZATIONS),
    ("DSCController", "start_on", P.START_ON), ("DSCController", "coupling", P.INPUT_COUPLINGS),
    ("MobileRobot", "coupling", P.INPUT_COUPLINGS[:2]),
])
def test_choices_are_fixed_integer_parameters_with_their_range(md, name, variable, choices):
    scalar_ = scalar(md[name], variable)
    assert (scalar_.type, scalar_.causality, scalar_.variability) == ("Integer", "parameter", "fixed")
    assert int(scalar_.start) == 0
    assert int(scalar_.min) == 0 and int(scalar_.max) == len(choices) - 1


@pytest.mark.parametrize("name", NAMES)
def test_start_values_are_the_papers_values(md, name):
    """Every parameter and input starts at its table value (to the last printed digit)."""
    variables = {v.name: v for v in md[name].modelVariables}
    problems = []
    for v in (*TABLES[name]["parameter"], *TABLES[name]["input"]):
        start = variables[v.name].start
        if start is None or not math.isclose(float(start), v.start, rel_tol=1e-15, abs_tol=1e-300):
            problems.append((v.name, start, v.start))
    assert problems == []


@pytest.mark.parametrize("name", [
    "ReferenceRobot",
    "MobileRobot",
    "DSCController",
])
def test_start_values_round_trip_exactly(md, name):
    """FMI 2.0: the start attribute is the FMU's initial value, so it must parse to the same double."""
    variables = {v.name: v for v in md[name].modelVariables}
    problems = [
        (v.name, variables[v.name].start, repr(v.start))
        for v in (*TABLES[name]["parameter"], *TABLES[name]["input"])
        if float(variables[v.name].start) != v.start
    ]
    assert problems == []


@pytest.mark.parametrize("name", NAMES)
def test_outputs_have_no_start_and_are_calculated(md, name):
    for v in md[name].modelVariables:
        if v.causality == "output":
            assert (v.name, v.initial, v.start) == (v.name, "calculated", None)


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_model_description_needs_no_execution_tool_in_either_interface(fmu_paths, fmu3_paths, version, name):
    """FMI's needsExecutionTool: "a tool is needed to execute the model and the FMU just contains the
    communication to this tool". Ours carry the model and the code that runs it (docs/other-tools.md)."""
    with zipfile.ZipFile((fmu_paths if version == 2 else fmu3_paths)[name]) as fmu:
        root = ElementTree.fromstring(fmu.read("modelDescription.xml"))
    declared = {tag: root.find(tag).get("needsExecutionTool") for tag in ("CoSimulation", "ModelExchange")}
    assert declared == {"CoSimulation": "false", "ModelExchange": "false"}


@pytest.mark.parametrize("name", NAMES)
def test_every_variable_has_a_description(md, name):
    assert [v.name for v in md[name].modelVariables if not (v.description or "").strip()] == []


@pytest.mark.parametrize("name", NAMES)
def test_every_real_has_its_tables_unit_declared_in_unit_definitions(md, name):
    declared = {u.name for u in md[name].unitDefinitions}
    table = {v.name: v.unit for group in (*TABLES[name].values(), FMUS[name].locals) for v in group}
    problems = []
    for v in md[name].modelVariables:
        if v.type != "Real":
            continue
        if v.unit is None or v.unit not in declared or v.unit != table[v.name]:
            problems.append((v.name, v.unit, table[v.name]))
    assert problems == []


@pytest.mark.parametrize("name", NAMES)
def test_bounds_of_the_tables_are_declared(md, name):
    variables = {v.name: v for v in md[name].modelVariables}
    for v in (*TABLES[name]["parameter"], *TABLES[name]["input"]):
        sv = variables[v.name]
        if v.bound == "nonnegative":
            assert float(sv.min) == 0.0, v.name
        if v.maximum is not None:
            assert float(sv.max) == v.maximum, v.name


# SI base-unit exponents worked out by hand: V = W/A = kg m2 s-3 A-1, Ohm = V/A, H = Ohm s, ...
BASE_UNITS = [
    ("MobileRobot", "V", dict(kg=1, m=2, s=-3, A=-1)),
    ("DSCController", "V", dict(kg=1, m=2, s=-3, A=-1)),
    ("MobileRobot", "Ohm", dict(kg=1, m=2, s=-3, A=-2)),
    ("MobileRobot", "H", dict(kg=1, m=2, s=-2, A=-2)),
    ("MobileRobot", "A", dict(A=1)),
    ("MobileRobot", "N.m/A", dict(kg=1, m=2, s=-2, A=-1)),
    ("MobileRobot", "V.s/rad", dict(kg=1, m=2, s=-2, A=-1, rad=-1)),
    ("MobileRobot", "N.m.s/rad", dict(kg=1, m=2, s=-1, rad=-1)),
    ("MobileRobot", "kg.m2", dict(kg=1, m=2)),
    ("MobileRobot", "rad/s", dict(rad=1, s=-1)),
    ("ReferenceRobot", "m/s2", dict(m=1, s=-2)),
    ("ReferenceRobot", "m/s", dict(m=1, s=-1)),
    ("DSCController", "1/m", dict(m=-1)),
    ("DSCController", "1", dict()),
]


@pytest.mark.parametrize("name,unit,exponents", BASE_UNITS, ids=[f"{n}-{u}" for n, u, _ in BASE_UNITS])
def test_base_unit_exponents(md, name, unit, exponents):
    units = {u.name: u for u in md[name].unitDefinitions}
    base = units[unit].baseUnit
    assert base is not None
    got = {k: getattr(base, k) for k in ("kg", "m", "s", "A", "K", "mol", "cd", "rad")}
    assert got == {k: exponents.get(k, 0) for k in got}
    assert (base.factor, base.offset) == (1.0, 0.0)


@pytest.mark.parametrize("name", NAMES)
def test_default_experiment_and_capabilities(md, name):
    experiment = md[name].defaultExperiment
    assert (float(experiment.startTime), float(experiment.stopTime), float(experiment.stepSize)) == (0.0, 30.0, 1e-3)
    cs = md[name].coSimulation
    assert cs.modelIdentifier == name
    assert cs.canGetAndSetFMUstate is True
    assert cs.canSerializeFMUstate is True
    me = md[name].modelExchange
    assert (me.modelIdentifier, me.canGetAndSetFMUstate, me.canSerializeFMUstate) == (name, True, True)
    assert me.needsCompletedIntegratorStep is False
    assert md[name].numberOfEventIndicators == len(FMUS[name].indicators)
    assert md[name].fmiVersion == "2.0"


@pytest.mark.parametrize("name", NAMES)
def test_model_structure_lists_every_output_state_and_derivative(md, name):
    outputs = [v.name for v in md[name].modelVariables if v.causality == "output"]
    states = [s.variable.name for s in FMUS[name].states]
    derivatives = [s.derivative.name for s in FMUS[name].states]
    assert [u.variable.name for u in md[name].outputs] == outputs
    assert [u.variable.name for u in md[name].derivatives] == derivatives
    assert [u.variable.derivative.name for u in md[name].derivatives] == states
    initial = [v.name for v in md[name].modelVariables if v.name in {*outputs, *states, *derivatives}]
    assert [u.variable.name for u in md[name].initialUnknowns] == initial
    for unknown in (*md[name].outputs, *md[name].derivatives):
        assert unknown.dependencies is not None, f"{unknown.variable.name}: no dependencies attribute"
        assert all(d.causality == "input" or d.name in states for d in unknown.dependencies), unknown.variable.name


# The outputs that depend on inputs: the plant's applied voltages and whether its drivers limit them (§5.14).
FEEDTHROUGH = {"u1_applied": ["u1"], "u2_applied": ["u2"], "saturation_active": ["u1", "u2"]}


@pytest.mark.parametrize("name", ("MobileRobot", "ReferenceRobot"))
def test_plant_and_reference_outputs_depend_on_no_input_but_the_drivers(md, name):
    assert {u.variable.name: [d.name for d in u.dependencies if d.causality == "input"] for u in md[name].outputs} == {
        n: FEEDTHROUGH.get(n, []) for n in EXPECTED[name]["output"]
    }


@pytest.mark.parametrize("output, other_current", (("u1", "i2"), ("u2", "i1")))
def test_controller_voltages_feed_through_every_input_but_the_other_wheels_current(md, output, other_current):
    """(26): u1 = -k5 (i1 - x3f1) - Phi2 W2_hat uses i1, never i2; through x3f_dot1 and x3bar (20) every
    other measurement and the reference enter."""
    unknown = {u.variable.name: u for u in md["DSCController"].outputs}[output]
    inputs = sorted(d.name for d in unknown.dependencies if d.causality == "input")
    assert inputs == sorted(set(EXPECTED["DSCController"]["input"]) - {other_current})


def test_controller_input_start_values_are_the_default_scenarios_initial_state(md):
    """The inputs' start values describe the paper's start: u before any set is the paper's u(0)."""
    starts = {v.name: v.start for v in md["DSCController"].modelVariables if v.causality == "input"}
    assert [float(starts[name]) for name in CONTROLLER_IN] == list(M_PAPER)


# --- FMU state ----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_serialized_fmu_state_round_trips_also_into_a_new_instance(new, name):
    integer, inputs, schedule = DRIVES[name]
    inst = new(name, integer=integer)
    h = 2e-3
    replay(inst, inputs, schedule, 0.0, 5, h)
    state = inst.fmu.getFMUstate()
    blob = inst.fmu.serializeFMUstate(state)
    assert isinstance(blob, bytes) and len(blob) > 0
    first = replay(inst, inputs, schedule, 5 * h, 6, h)

    restored = inst.fmu.deSerializeFMUstate(blob)
    inst.fmu.setFMUstate(restored)
    assert replay(inst, inputs, schedule, 5 * h, 6, h) == first

    other = new(name)  # default parameters: the state carries them over
    other_state = other.fmu.deSerializeFMUstate(blob)
    other.fmu.setFMUstate(other_state)
    assert replay(other, inputs, schedule, 5 * h, 6, h) == first
    for fmu, s in ((inst.fmu, state), (inst.fmu, restored), (other.fmu, other_state)):
        fmu.freeFMUstate(s)


# --- errors -------------------------------------------------------------------------------------

INF, NAN = float("inf"), float("nan")
# One bad value of each kind (every bad value is tried in this process: test_slave_behaviour.py).
# (FMU, kind, variable, value): "input" and "tunable" set in step mode, "parameter"/"integer" in initialization mode
ONE_OF_EACH_KIND = [
    ("MobileRobot", "input", "u1", NAN),
    ("DSCController", "input", "v_r", 0.0),
    ("DSCController", "parameter", "tau2", 0.0),
    ("MobileRobot", "tunable", "max_step", 0.0),
    ("ReferenceRobot", "integer", "profile", 7),
]


def _healthy_run(md, unzipped, name):
    integer, inputs, schedule = DRIVES[name]
    inst = Instance(md[name], unzipped[name], "healthy").initialize(integer=integer)
    rows = replay(inst, inputs, schedule, 0.0, 5, 1e-3)
    inst.close()
    return rows


@pytest.fixture(scope="module")
def healthy(md, fmu_unzipped):
    """What each FMU gives for a short drive, recorded before any bad value is tried."""
    return {name: _healthy_run(md, fmu_unzipped, name) for name in NAMES}


@pytest.mark.parametrize("name,kind,variable,value", ONE_OF_EACH_KIND,
                         ids=[f"{n}-{k}-{v}={x}" for n, k, v, x in ONE_OF_EACH_KIND])
def test_bad_value_is_refused_named_and_holds_the_fmu_until_corrected(
        md, fmu_unzipped, healthy, name, kind, variable, value):
    """The set call succeeds, the refusal reaches the importer's logger as an error naming the
    variable and its range, and doStep returns fmi2Discard while it is refused. The discarded step
    leaves the FMU in stepFailed (FMI 2.0.4, 4.2.4), where nothing may be set: the state saved before
    the step leads back, and a valid value set there lets the step through; a fixed parameter, which
    cannot be set after initialisation, needs a reset. Freed, the FMU runs as before in this process."""
    inst = Instance(md[name], fmu_unzipped[name], "bad")
    fmu, ref = inst.fmu, inst.vr[variable]
    get = fmu.getInteger if kind == "integer" else fmu.getReal
    put = fmu.setInteger if kind == "integer" else fmu.setReal
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    if kind in ("input", "tunable"):
        fmu.exitInitializationMode()
        fmu.doStep(0.0, 1e-3)
    before = get([ref])
    put([ref], [value])
    assert get([ref]) == before
    named = re.compile(rf"(?<![\w.]){re.escape(variable)} = ")
    errors = [message for status, message in inst.messages() if status >= FMI2_ERROR]
    assert any(named.search(message) and "allowed" in message for message in errors), errors
    if kind not in ("input", "tunable"):
        fmu.exitInitializationMode()
    saved = fmu.getFMUstate()
    with pytest.raises(FMICallException) as failure:
        fmu.doStep(1e-3, 1e-3)
    assert (failure.value.function, failure.value.status) == ("fmi2DoStep", FMI2_DISCARD)
    with pytest.raises(FMICallException) as refused:
        put([ref], before)
    assert refused.value.status == FMI2_ERROR and "not allowed in state step failed" in inst.messages()[-1][1]
    fmu.setFMUstate(saved)
    fmu.freeFMUstate(saved)
    if inst.variables[variable].variability == "fixed":
        # A fixed parameter cannot be set once initialisation has ended: a reset starts over.
        with pytest.raises(FMICallException) as refused:
            put([ref], before)
        assert refused.value.status == FMI2_ERROR
        assert "fixed parameter" in inst.messages()[-1][1]
        fmu.reset()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
    else:
        put([ref], before)
    fmu.doStep(1e-3, 1e-3)
    inst.close()
    gc.collect()
    assert _healthy_run(md, fmu_unzipped, name) == healthy[name]


FREE_AFTER_REFUSAL = textwrap.dedent("""
    import gc, sys
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave
    path, unzipped = sys.argv[1], sys.argv[2]
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    for k in range(20):
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="MobileRobot", instanceName=f"m{k}")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0); fmu.enterInitializationMode(); fmu.exitInitializationMode()
        fmu.setReal([vr["u1"]], [float("nan")])  # refused with fmi2OK: fmpy raises for any worse status
        fmu.freeInstance()   # what an importer does when it gives up on an instance
        gc.collect()
        print(f"cycle {k} done", flush=True)
    print("survived")
""")


def test_freeing_an_instance_after_a_refused_value_does_not_crash(fmu_paths, fmu_unzipped):
    """In a process of its own, so that a crash fails the test instead of ending the session."""
    run = subprocess.run(
        [sys.executable, "-c", FREE_AFTER_REFUSAL, str(fmu_paths["MobileRobot"]), str(fmu_unzipped["MobileRobot"])],
        capture_output=True, text=True, timeout=120,
    )
    assert (run.returncode, run.stdout.strip().splitlines()[-1:]) == (0, ["survived"]), (
        run.stdout[-500:] + run.stderr[-2000:])


RAISING = """
    def do_step(self, current_time, step_size):
        if self.u[0] == 123.0:
            raise RuntimeError("injected failure")
        return super().do_step(current_time, step_size)
"""


def test_an_exception_in_the_model_discards_the_step_and_the_state_api_rolls_back(patched_mobile_robot, tmp_path):
    """A Python exception inside a step is fmi2Discard with the exception in the log, never
    fmi2Fatal; the instance answers afterwards and fmi2SetFMUstate brings it back exactly."""
    path = patched_mobile_robot('    """A ``MobileRobotModel`` in the FMI 2.0 slave (pythonfmu)."""\n', RAISING, "raising")
    plant = Instance(read_model_description(str(path)), extract(str(path), unzipdir=tmp_path / "u"), "raising")
    plant.initialize()
    plant.set(("u1", "u2"), (6.0, 5.0))
    plant.step(0.0, 0.01)
    saved = plant.fmu.getFMUState()
    expected = Instance(plant.md, plant.fmu.unzipDirectory, "twin").initialize()
    expected.set(("u1", "u2"), (6.0, 5.0))
    expected.step(0.0, 0.01)
    expected.step(0.01, 0.01)
    plant.set(("u1",), (123.0,))
    with pytest.raises(FMICallException) as failure:
        plant.step(0.01, 0.01)
    assert failure.value.status == FMI2_DISCARD
    assert any(s == FMI2_DISCARD and "RuntimeError: injected failure" in m for s, m in plant.messages())
    assert not any(s == FMI2_FATAL for s, _ in plant.messages())
    plant.fmu.setFMUstate(saved)
    plant.step(0.01, 0.01)
    assert plant.get(PLANT_OUT) == expected.get(PLANT_OUT)
    plant.fmu.freeFMUstate(saved)
    plant.close()
    expected.close()


WIDE = """
    def get_integer(self, vrs):
        return [2 ** 40 for _ in vrs] if self.u[0] == 123.0 else super().get_integer(vrs)

    def do_step(self, current_time, step_size):
        if self.u[0] == 123.0:
            raise RuntimeError("100% " + "x" * 5000 + " end")
        return super().do_step(current_time, step_size)
"""


def test_an_integer_beyond_32_bits_is_an_error_and_a_long_message_arrives_whole(patched_mobile_robot, tmp_path):
    """A getter's integer that an fmi2Integer cannot hold is fmi2Error with one line naming it (not a value
    cut to 32 bits); an exception's message of 5,000 characters reaches the logger whole, its '%' doubled
    for the logger's format."""
    path = patched_mobile_robot('    """A ``MobileRobotModel`` in the FMI 2.0 slave (pythonfmu)."""\n', WIDE, "wide")
    plant = Instance(read_model_description(str(path)), extract(str(path), unzipdir=tmp_path / "u"), "wide")
    plant.initialize()
    plant.set(("u1",), (123.0,))
    with pytest.raises(FMICallException) as failure:
        plant.step(0.0, 0.01)
    assert failure.value.status == FMI2_DISCARD
    assert any(m.endswith("RuntimeError: 100%% " + "x" * 5000 + " end") for _, m in plant.messages())
    with pytest.raises(FMICallException) as failure:
        plant.fmu.getInteger([plant.vr["coupling"]])
    assert failure.value.status == FMI2_ERROR
    assert (FMI2_ERROR, f"{plant.name}: get_integer returned {2 ** 40} for value reference {plant.vr['coupling']}; "
            "allowed: -2147483648 to 2147483647 (an Integer has 32 bits)") in plant.messages()
    plant.fmu.freeInstance()


def test_messages_reach_the_importers_logger_with_their_status_and_category(new):
    """The guard's warning, a refusal's error and the discarded step: each through fmi2CallbackLogger,
    with the status the slave gave it and that status's category."""
    ctrl = new("DSCController")
    ctrl.set(CONTROLLER_IN, M_GUARD)
    ctrl.step(0.0, 1e-3)
    ctrl.set(("k1",), (-2.0,))
    with pytest.raises(FMICallException):
        ctrl.step(1e-3, 1e-3)
    records = [(status, category, message) for name, status, category, message in LOG.records if name == ctrl.name]
    assert [record[:2] for record in records] == [
        (FMI2_WARNING, "logStatusWarning"), (FMI2_ERROR, "logStatusError"), (FMI2_DISCARD, "logStatusDiscard"),
    ]
    assert ["beta = " in records[0][2], "k1 = -2.0" in records[1][2], "discarded" in records[2][2]] == [True] * 3


# --- the three FMUs together --------------------------------------------------------------------


def _closed_loop(md, unzipped, steps=500, h=1e-3):
    ref = Instance(md["ReferenceRobot"], unzipped["ReferenceRobot"], "loop").initialize()
    plant = Instance(md["MobileRobot"], unzipped["MobileRobot"], "loop").initialize()
    ctrl = Instance(md["DSCController"], unzipped["DSCController"], "loop").initialize()
    rows = []
    for k in range(steps):
        m = plant.get(PLANT_OUT) + ref.get(REFERENCE_OUT)
        ctrl.set(CONTROLLER_IN, m)
        u = ctrl.get(("u1", "u2"))
        plant.set(("u1", "u2"), u)
        rows.append((k * h, *m, *u))
        for inst in (ref, plant, ctrl):
            inst.step(k * h, h)
    rows.append((steps * h, *plant.get(PLANT_OUT), *ref.get(REFERENCE_OUT), *ctrl.get(("u1", "u2"))))
    for inst in (ref, plant, ctrl):
        inst.close()
    return rows


def test_three_fmus_in_one_process_twice_give_identical_results(md, fmu_unzipped):
    first = _closed_loop(md, fmu_unzipped)
    second = _closed_loop(md, fmu_unzipped)
    assert first == second
    assert all(math.isfinite(v) for row in first for v in row)
    # The loop is closed: the plant moved under the controller's voltages.
    start, end = first[0], first[-1]
    assert max(abs(row[-1]) for row in first) > 1.0
    assert math.hypot(end[1] - start[1], end[2] - start[2]) > 1e-3


def test_bundled_package_names_are_unique_per_fmu_and_build(fmu_paths):
    packages = {}
    for name, path in fmu_paths.items():
        digest = fmu_build_id(path)
        with zipfile.ZipFile(path) as archive:
            module = archive.read("resources/slavemodule.txt").decode().strip()
            files = archive.namelist()
            script = archive.read(f"resources/{module}.py").decode()
        assert module == f"{Path(FMUS[name].script).stem}_{digest[:12]}"
        package = f"dsc_fmu_{name.lower()}_{digest[:12]}"
        assert {f"resources/{package}/fmu/slave.py", f"resources/{package}/fmu/fmi2.py"} <= set(files)
        assert f"resources/{package}/fmu/fmi3.py" not in files  # an FMI 2.0 FMU never needs pythonfmu3
        assert f"resources/{package}/models/plant.py" in files
        assert "from dsc_fmu." not in script and f"from {package}." in script
        assert not any(f.startswith("resources/dsc_fmu/") for f in files)
        packages[name] = package
    assert len(set(packages.values())) == 3


def test_two_builds_with_different_sources_coexist_in_one_process(fmu_paths, fmu_unzipped, md, tmp_path,
                                                                 patched_mobile_robot):
    """A second MobileRobot built from changed sources: own names, own code, both run side by side."""
    shifted = "\n    def output_values(self):\n        x_, *rest = super().output_values()\n        return [x_ + 1000.0, *rest]\n"
    variant = patched_mobile_robot('    """A ``MobileRobotModel`` in the FMI 2.0 slave (pythonfmu)."""\n', shifted, "variant")

    original = fmu_paths["MobileRobot"]
    ids = fmu_build_id(original), fmu_build_id(variant)
    assert ids[0] != ids[1]
    modules = []
    for path, digest in zip((original, variant), ids):
        with zipfile.ZipFile(path) as archive:
            module = archive.read("resources/slavemodule.txt").decode().strip()
            assert digest[:12] in module
            assert any(f.startswith(f"resources/dsc_fmu_mobilerobot_{digest[:12]}/") for f in archive.namelist())
            modules.append(f"dsc_fmu_mobilerobot_{digest[:12]}.{module}")
    assert modules[0] != modules[1]

    variant_md = read_model_description(str(variant))
    variant_dir = extract(str(variant), unzipdir=tmp_path / "variant_unzipped")
    a = Instance(md["MobileRobot"], fmu_unzipped["MobileRobot"], "orig").initialize()
    b = Instance(variant_md, variant_dir, "variant").initialize()
    c = Instance(md["MobileRobot"], fmu_unzipped["MobileRobot"], "orig").initialize()
    for inst in (a, b, c):
        inst.set(("u1", "u2"), (6.0, 5.0))
    for k in range(10):
        for inst in (a, b, c):
            inst.step(k * 0.01, 0.01)
    xa, xb, xc = (inst.get(PLANT_OUT) for inst in (a, b, c))
    assert xa == xc
    assert xb[0] == pytest.approx(xa[0] + 1000.0, abs=1e-9)
    assert xb[1:] == xa[1:]
    for module in modules:
        assert module in sys.modules
    for inst in (a, b, c):
        inst.close()
    assert not any(name.startswith("dsc_fmu_mobilerobot_") for name in sys.modules)


@pytest.mark.parametrize("name", NAMES)
def test_an_fmu_instantiates_again_after_its_instances_are_freed(md, fmu_unzipped, name):
    """Freeing the last instance forgets the build's modules, the slave script's among them
    (native_bridge.release); each new instance imports them again and finds its class."""
    for cycle in range(3):
        inst = Instance(md[name], fmu_unzipped[name], f"again{cycle}").initialize()
        inst.step(0.0, 1e-3)
        assert all(math.isfinite(float(v)) for v in inst.outputs().values())
        inst.close()
