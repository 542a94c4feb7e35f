"""The three FMUs through fmpy: model descriptions, behaviour, state, errors, coexistence.

Expectations come from the variable tables (dsc_fmu.models.parameters), the FMI 2.0 standard,
the interface names of the issue and closed-form solutions of the equations in docs/model.md; never
from numbers copied from the FMUs' own output.
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
from dsc_fmu.models.controller import control_law, gains, initial_controller_state, start_filters

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
FMI2_OK, FMI2_WARNING, FMI2_DISCARD, FMI2_ERROR, FMI2_FATAL = range(5)

# --- the interface of the issue (part of the product) -------------------------------------------

EXPECTED = {
    "MobileRobot": {
        "parameter": (
            "R", "d", "r", "mc", "mw", "Ic", "Iw", "Im", "d11", "d22", "Ra1", "Ra2", "La1", "La2",
            "KE1", "KE2", "KT1", "KT2", "N1", "N2", "x0", "y0", "theta0",
            "omega1_0", "omega2_0", "i1_0", "i2_0", "coupling", "max_step",
        ),
        "input": ("u1", "u2"),
        "output": ("x", "y", "theta", "theta_dot", "omega1", "omega2", "i1", "i2"),
    },
    "ReferenceRobot": {
        "parameter": ("x0", "y0", "theta0", "profile", "vr0", "wr0", "eight_A", "eight_B", "eight_T", "max_step"),
        "input": (),
        "output": ("x_r", "y_r", "theta_r", "v_r", "omega_r", "v_r_dot"),
    },
    "DSCController": {
        "parameter": (
            "k1", "k2", "k3", "k4", "k5", "gamma1", "gamma2", "sigma1", "sigma2", "sigma3", "sigma4",
            "tau2", "tau3", *(f"Gamma1_{i}" for i in range(1, 9)), *(f"Gamma2_{i}" for i in range(1, 7)),
            "a1_hat0", "a2_hat0", *(f"W1_hat0_{i}" for i in range(1, 9)), *(f"W2_hat0_{i}" for i in range(1, 7)),
            "discretization", "start_on", "coupling", "beta_min", "max_step",
        ),
        "input": (
            "x", "y", "theta", "theta_dot", "omega1", "omega2", "i1", "i2",
            "x_r", "y_r", "theta_r", "v_r", "omega_r", "v_r_dot",
        ),
        "output": (
            "u1", "u2", "S11", "S12", "S13", "a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm",
            *(f"W1_hat_{i}" for i in range(1, 9)), *(f"W2_hat_{i}" for i in range(1, 7)),
            "beta", "beta_guard_count", "beta_guard_active", "started",
        ),
    },
}

TABLES = {
    "ReferenceRobot": {"parameter": P.REFERENCE_PARAMETERS, "input": (), "output": P.REFERENCE_OUTPUTS},
    "MobileRobot": {"parameter": P.PLANT_PARAMETERS, "input": P.PLANT_INPUTS, "output": P.PLANT_OUTPUTS},
    "DSCController": {
        "parameter": P.CONTROLLER_PARAMETERS, "input": P.CONTROLLER_INPUTS, "output": P.CONTROLLER_OUTPUTS,
    },
}
# Outputs registered outside the tables (docs/model.md §5: the beta guard made visible), with their FMI type.
EXTRA_OUTPUTS = {"DSCController": {"beta_guard_count": "Integer", "beta_guard_active": "Boolean", "started": "Boolean"}}

PLANT = P.defaults(P.PLANT_PARAMETERS)
REFERENCE = P.defaults(P.REFERENCE_PARAMETERS)
CONTROLLER = P.defaults(P.CONTROLLER_PARAMETERS)
PLANT_OUT = tuple(v.name for v in P.PLANT_OUTPUTS)
REFERENCE_OUT = tuple(v.name for v in P.REFERENCE_OUTPUTS)
CONTROLLER_IN = tuple(v.name for v in P.CONTROLLER_INPUTS)

# Measurements at the paper's initial condition (robot at (2.5, 1, pi/2), reference at (2, 2, 0)).
M_PAPER = [2.5, 1.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]
M_OTHER = [2.4, 1.1, 1.4, 0.1, 0.5, 0.4, 0.2, 0.1, 2.05, 2.0, 0.02, 0.9, 0.25, 0.1]
# Robot 1 m ahead of the reference on its heading: S11 = -1, beta = 1 - k1 vr = -1 < beta_min.
M_GUARD = [3.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]


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


@pytest.mark.parametrize("name", ("MobileRobot", "ReferenceRobot"))
def test_plant_and_reference_outputs_depend_on_no_input(md, name):
    assert {u.variable.name: [d.name for d in u.dependencies if d.causality == "input"] for u in md[name].outputs} == {
        n: [] for n in EXPECTED[name]["output"]
    }


@pytest.mark.parametrize("output, other_current", (("u1", "i2"), ("u2", "i1")))
def test_controller_voltages_feed_through_every_input_but_the_other_wheels_current(md, output, other_current):
    """(26): u1 = -k5 (i1 - x3f1) - Phi2 W2_hat uses i1, never i2; through x3f_dot1 and x3bar (20) every
    other measurement and the reference enter."""
    unknown = {u.variable.name: u for u in md["DSCController"].outputs}[output]
    inputs = sorted(d.name for d in unknown.dependencies if d.causality == "input")
    assert inputs == sorted(set(EXPECTED["DSCController"]["input"]) - {other_current})


def test_plant_outputs_do_not_move_with_the_inputs(new):
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (3.0, -2.0))
    plant.step(0.0, 0.01)
    before = plant.outputs()
    plant.set(("u1", "u2"), (50.0, 40.0))
    assert plant.outputs() == before


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


# --- behaviour ----------------------------------------------------------------------------------


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


def test_controller_state_follows_inputs_until_the_first_step(md, fmu_unzipped):
    """Until the first fmi2DoStep, x2f = x2bar and x3f = x3bar of the current inputs, in
    initialisation mode and after it, whatever was read before; the first step starts from the
    inputs it holds (so no order of sets and reads can latch stale start values)."""
    inst = Instance(md["DSCController"], fmu_unzipped["DSCController"], "init")
    g = gains(CONTROLLER)
    inst.fmu.setupExperiment(startTime=0.0)
    inst.fmu.enterInitializationMode()

    def expect(m, state=None):
        x = state or start_filters(g, initial_controller_state(CONTROLLER), m)
        law = control_law(g, x, m)
        assert inst.get(("u1", "u2")) == pytest.approx([law.u1, law.u2], rel=1e-12, abs=1e-12)

    for m in (M_PAPER, M_OTHER):
        inst.set(CONTROLLER_IN, m)
        expect(m)
    inst.fmu.exitInitializationMode()
    for m in (M_PAPER, M_OTHER):
        inst.set(CONTROLLER_IN, m)
        expect(m)
    assert inst.outputs()["started"] is False
    inst.step(0.0, 1e-3)
    assert inst.outputs()["started"] is True
    inst.close()


def test_controller_input_start_values_are_the_default_scenarios_initial_state(md):
    """The inputs' start values describe the paper's start: u before any set is the paper's u(0)."""
    starts = {v.name: v.start for v in md["DSCController"].modelVariables if v.causality == "input"}
    assert [float(starts[name]) for name in CONTROLLER_IN] == list(M_PAPER)


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


def test_reference_profile_starts_at_the_experiments_start_time(md, fmu_unzipped):
    A, B, T = REFERENCE["eight_A"], REFERENCE["eight_B"], REFERENCE["eight_T"]
    ref = Instance(md["ReferenceRobot"], fmu_unzipped["ReferenceRobot"], "t5")
    ref.initialize(integer={"profile": 1}, start_time=5.0)
    assert ref.get(REFERENCE_OUT[:3]) == [REFERENCE["x0"], REFERENCE["y0"], REFERENCE["theta0"]]
    assert ref.get1("v_r") == pytest.approx(_eight(5.0, A, B, T)[2], rel=1e-12)
    ref.step(5.0, 0.1)
    assert ref.get1("v_r") == pytest.approx(_eight(5.1, A, B, T)[2], rel=1e-12)
    ref.close()


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


# --- FMU state ----------------------------------------------------------------------------------

DRIVES = {
    "ReferenceRobot": ({"profile": 1}, [], lambda k: []),
    "MobileRobot": ({}, ["u1", "u2"], lambda k: [10.0 + k, 8.0 - 0.5 * k]),
    "DSCController": ({}, list(CONTROLLER_IN), lambda k: [m + 0.01 * k for m in M_GUARD]),
}


def _replay(instance, inputs, schedule, t0, steps, h):
    rows = []
    for k in range(steps):
        if inputs:
            instance.set(inputs, schedule(k))
        rows.append(instance.outputs())
        instance.step(t0 + k * h, h)
    rows.append(instance.outputs())
    return rows


@pytest.mark.parametrize("name", NAMES)
def test_get_and_set_fmu_state_replays_identically(new, name):
    integer, inputs, schedule = DRIVES[name]
    inst = new(name, integer=integer)
    h = 2e-3
    _replay(inst, inputs, schedule, 0.0, 5, h)
    state = inst.fmu.getFMUstate()
    first = _replay(inst, inputs, schedule, 5 * h, 6, h)
    inst.fmu.setFMUstate(state)
    second = _replay(inst, inputs, schedule, 5 * h, 6, h)
    assert second == first
    assert first[0] != first[-1]
    if name == "DSCController":
        assert first[-1]["beta_guard_count"] > first[0]["beta_guard_count"] > 0
    inst.fmu.freeFMUstate(state)


@pytest.mark.parametrize("name", NAMES)
def test_fmu_state_before_the_first_step(new, name):
    integer, inputs, schedule = DRIVES[name]
    inst = new(name, integer=integer)
    state = inst.fmu.getFMUstate()
    first = _replay(inst, inputs, schedule, 0.0, 4, 1e-3)
    inst.fmu.setFMUstate(state)
    assert _replay(inst, inputs, schedule, 0.0, 4, 1e-3) == first
    inst.fmu.freeFMUstate(state)


@pytest.mark.parametrize("name", NAMES)
def test_serialized_fmu_state_round_trips_also_into_a_new_instance(new, name):
    integer, inputs, schedule = DRIVES[name]
    inst = new(name, integer=integer)
    h = 2e-3
    _replay(inst, inputs, schedule, 0.0, 5, h)
    state = inst.fmu.getFMUstate()
    blob = inst.fmu.serializeFMUstate(state)
    assert isinstance(blob, bytes) and len(blob) > 0
    first = _replay(inst, inputs, schedule, 5 * h, 6, h)

    restored = inst.fmu.deSerializeFMUstate(blob)
    inst.fmu.setFMUstate(restored)
    assert _replay(inst, inputs, schedule, 5 * h, 6, h) == first

    other = new(name)  # default parameters: the state carries them over
    other_state = other.fmu.deSerializeFMUstate(blob)
    other.fmu.setFMUstate(other_state)
    assert _replay(other, inputs, schedule, 5 * h, 6, h) == first
    for fmu, s in ((inst.fmu, state), (inst.fmu, restored), (other.fmu, other_state)):
        fmu.freeFMUstate(s)


def test_fmu_state_restores_inputs_and_tunable_parameters(new):
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (4.0, 5.0))
    plant.step(0.0, 0.01)
    state = plant.fmu.getFMUstate()
    expected = plant.outputs()
    plant.set(("u1", "u2", "max_step"), (-7.0, 9.0, 0.01))
    plant.step(0.01, 0.01)
    plant.fmu.setFMUstate(state)
    assert plant.get(("u1", "u2", "max_step")) == [4.0, 5.0, PLANT["max_step"]]
    assert plant.outputs() == expected
    plant.fmu.freeFMUstate(state)


# --- internal sub-steps -------------------------------------------------------------------------


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


# --- errors -------------------------------------------------------------------------------------

INF, NAN = float("inf"), float("nan")
BAD_VALUES = [
    # (FMU, kind, variable, value): "input" set in step mode, "parameter"/"integer" in initialization mode
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


def _healthy_run(md, unzipped, name):
    integer, inputs, schedule = DRIVES[name]
    inst = Instance(md[name], unzipped[name], "healthy").initialize(integer=integer)
    rows = _replay(inst, inputs, schedule, 0.0, 5, 1e-3)
    inst.close()
    return rows


@pytest.fixture(scope="module")
def healthy(md, fmu_unzipped):
    """What each FMU gives for a short drive, recorded before any bad value is tried."""
    return {name: _healthy_run(md, fmu_unzipped, name) for name in NAMES}


@pytest.mark.parametrize("name,kind,variable,value", BAD_VALUES,
                         ids=[f"{n}-{k}-{v}={x}" for n, k, v, x in BAD_VALUES])
def test_bad_value_is_refused_named_and_holds_the_fmu_until_corrected(
        md, fmu_unzipped, healthy, name, kind, variable, value):
    """The value is refused with an error naming the variable and its range, the variable keeps its
    last valid value, and doStep returns fmi2Discard while it is refused (see DscSlave). The
    discarded step leaves the FMU in stepFailed (FMI 2.0.4, 4.2.4), where nothing may be set: the
    state saved before the step leads back, and a valid value set there lets the step through."""
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


FREE_AFTER_FATAL = textwrap.dedent("""
    import gc, sys
    from fmpy import read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave
    path, unzipped = sys.argv[1], sys.argv[2]
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    for k in range(20):
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="MobileRobot", instanceName=f"m{k}")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0); fmu.enterInitializationMode(); fmu.exitInitializationMode()
        try:
            fmu.setReal([vr["u1"]], [float("nan")])
        except FMICallException:
            pass
        fmu.freeInstance()   # what an importer does when it gives up on a failed instance
        gc.collect()
        print(f"cycle {k} done", flush=True)
    print("survived")
""")


def test_freeing_an_instance_after_a_rejected_value_does_not_crash(fmu_paths, fmu_unzipped):
    run = subprocess.run(
        [sys.executable, "-c", FREE_AFTER_FATAL, str(fmu_paths["MobileRobot"]), str(fmu_unzipped["MobileRobot"])],
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
    path = patched_mobile_robot('    """``MobileRobotModel`` on the FMI 2.0 glue (pythonfmu)."""\n', RAISING, "raising")
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


def test_non_finite_state_discards_the_step_and_keeps_the_instance_usable(new):
    plant = new("MobileRobot")
    plant.set(("u1", "u2"), (1e308, 1e308))  # finite and allowed, but u / La overflows the state
    before = plant.get(PLANT_OUT)
    saved = plant.fmu.getFMUstate()
    with pytest.raises(FMICallException) as failure:
        plant.step(0.0, 0.01)
    assert failure.value.status == FMI2_DISCARD
    assert any("not finite" in message for _, message in plant.messages())
    assert plant.get(PLANT_OUT) == before
    plant.fmu.setFMUstate(saved)  # out of stepFailed, where nothing may be set
    plant.fmu.freeFMUstate(saved)
    plant.set(("u1", "u2"), (5.0, 5.0))
    plant.step(0.0, 0.01)
    assert all(math.isfinite(v) for v in plant.get(PLANT_OUT))


def test_beta_guard_is_counted_shown_and_logged(new):
    ctrl = new("DSCController")
    ctrl.set(CONTROLLER_IN, M_GUARD)
    out = ctrl.outputs()
    assert out["beta"] < CONTROLLER["beta_min"] and out["beta_guard_active"] is True
    for k in range(3):
        ctrl.step(k * 1e-3, 1e-3)
    out = ctrl.outputs()
    assert out["beta_guard_count"] == 3
    assert all(math.isfinite(out[n]) for n in ("u1", "u2"))
    warnings = [m for s, m in ctrl.messages() if s == FMI2_WARNING and "beta" in m]
    assert warnings
    ctrl.set(CONTROLLER_IN, M_PAPER)
    assert ctrl.outputs()["beta_guard_active"] is False


def test_start_on_valid_inputs_waits_then_starts_from_the_first_valid_inputs(new):
    """start_on = valid_inputs: all-zero inputs (v_r = 0), as a master without an initial exchange
    gives them, make the controller wait (u = 0, steps accepted, one warning); the first valid
    inputs start it exactly as a controller that saw them first; after that v_r = 0 is refused."""
    h = 1e-3
    ctrl = new("DSCController", integer={"start_on": P.START_ON.index("valid_inputs")})
    ctrl.set(CONTROLLER_IN, [0.0] * len(CONTROLLER_IN))
    out = ctrl.outputs()
    assert (out["u1"], out["u2"], out["S11"], out["beta"], out["a1_hat"], out["started"]) == (0, 0, 0, 1, 0, False)
    ctrl.step(0.0, h)
    ctrl.step(h, h)
    assert ctrl.outputs()["started"] is False and ctrl.get(("u1", "u2")) == [0.0, 0.0]
    waits = [m for s, m in ctrl.messages() if s == FMI2_WARNING and "waits for valid inputs" in m]
    assert len(waits) == 1 and "v_r = 0.0" in waits[0] and "t = 0 s" in waits[0]
    assert not [m for s, m in ctrl.messages() if s >= FMI2_ERROR]
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
    with pytest.raises(FMICallException) as failure:
        ctrl.step(3 * h, h)
    assert failure.value.status == FMI2_DISCARD
    assert any(s == FMI2_ERROR and "v_r = 0.0" in m for s, m in ctrl.messages())


def test_start_on_valid_inputs_does_not_wait_for_a_refused_parameter(new):
    ctrl = new("DSCController", integer={"start_on": P.START_ON.index("valid_inputs")})
    ctrl.set(("tau2",), (0.0,))
    ctrl.set(CONTROLLER_IN, [0.0] * len(CONTROLLER_IN))
    with pytest.raises(FMICallException) as failure:
        ctrl.step(0.0, 1e-3)
    assert failure.value.status == FMI2_DISCARD
    assert any(s == FMI2_ERROR and "tau2 = 0.0" in m for s, m in ctrl.messages())


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
        assert {f"resources/{package}/fmu/glue.py", f"resources/{package}/fmu/fmi2.py"} <= set(files)
        assert f"resources/{package}/fmu/fmi3.py" not in files  # an FMI 2.0 FMU never needs pythonfmu3
        assert f"resources/{package}/models/plant.py" in files
        assert "from dsc_fmu." not in script and f"from {package}." in script
        assert not any(f.startswith("resources/dsc_fmu/") for f in files)
        packages[name] = package
    assert len(set(packages.values())) == 3


def test_two_builds_with_different_sources_coexist_in_one_process(fmu_paths, fmu_unzipped, md, tmp_path,
                                                                 patched_mobile_robot):
    """A second MobileRobot built from changed sources: own names, own code, both run side by side."""
    shifted = "\n    def outputs(self, x):\n        x_, *rest = super().outputs(x)\n        return [x_ + 1000.0, *rest]\n"
    variant = patched_mobile_robot('    """``MobileRobotModel`` on the FMI 2.0 glue (pythonfmu)."""\n', shifted, "variant")

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
