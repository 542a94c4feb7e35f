"""Model exchange: each FMU as an ODE through fmpy (FMI 2.0 and 3.0), against its own co-simulation,
the equations, its declared dependencies and the reference solution; the switches held between events."""

import ctypes
import math

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException

from dsc_fmu.cosim.instance import load_fmu, logging_callbacks
from dsc_fmu.cosim.model_exchange import simulate_model_exchange
from dsc_fmu.cosim.reference_solution import reference_solution
from dsc_fmu.models import parameters as P
from dsc_fmu.models.controller import control_law, gains, initial_controller_state, start_filters
from dsc_fmu.registry import FMUS
from dsc_fmu.scenario import load_scenario

NAMES = tuple(FMUS)
CONTROLLER_START = {v.name: v.start for v in P.CONTROLLER_INPUTS}


def _inputs(name: str, stop: float) -> np.ndarray | None:
    """Constant inputs for ``name`` alone over [0, stop] (fmpy's model-exchange route applies inputs at
    output points and in its root function, not in its right-hand side: only constant inputs mean the
    same to both routes): voltages that drive the plant forward and turning, a robot beside a moving
    reference for the controller."""
    if name == "MobileRobot":
        signal = np.zeros(2, dtype=[("time", float), ("u1", float), ("u2", float)])
        signal["u1"], signal["u2"] = 50.0, 40.0
    elif name == "DSCController":
        signal = np.zeros(2, dtype=[("time", float), *((v.name, float) for v in P.CONTROLLER_INPUTS)])
        for v in P.CONTROLLER_INPUTS:
            signal[v.name] = v.start
        signal["omega1"], signal["omega2"], signal["i1"] = 3.0, 2.0, 1.5
    else:
        return None
    signal["time"] = (0.0, stop)
    return signal


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_each_fmu_as_an_ode_agrees_with_its_co_simulation(fmu_paths, fmu3_paths, name, version):
    """fmpy's model-exchange route (CVode at 1e-10) against the same FMU's co-simulation (RK4 at 0.1 ms):
    the same equations through the other interface of the same binary."""
    path = str((fmu_paths if version == 2 else fmu3_paths)[name])
    kwargs = dict(stop_time=2.0, output_interval=0.01, input=_inputs(name, 2.0))
    me = simulate_fmu(path, fmi_type="ModelExchange", relative_tolerance=1e-10, **kwargs)
    cs = simulate_fmu(path, fmi_type="CoSimulation", step_size=1e-4, start_values={"max_step": 1e-4}, **kwargs)
    worst = {}
    for v in FMUS[name].outputs:
        scale = max(1.0, np.max(np.abs(cs[v.name])))
        worst[v.name] = np.max(np.abs(me[v.name] - cs[v.name])) / scale
    assert max(worst.values()) < 1e-7, worst


class Model:
    """One model-exchange instance of an FMU as the masters load it (``instance.load_fmu``): ``loaded``, and
    ``fmu`` its fmpy instance; ``log`` collects its messages as ``LogMessage``s."""

    def __init__(self, path, folder, name, log):
        self._callbacks = logging_callbacks(log)
        folder.mkdir(parents=True, exist_ok=True)
        self.loaded = load_fmu(name, path, folder, log, self._callbacks, model_exchange=True)
        self.md, self.log = read_model_description(str(path)), log
        self.version, self.fmu = self.loaded.fmi_version, self.loaded.instance
        self.refs = {name: v.valueReference for name, v in self.loaded.variables.items()}
        self.nx, self.nz = self.loaded.states, self.loaded.indicators
        self.loaded.enter_initialization(None, {})

    def set(self, values: dict):
        self.loaded.set_floats([self.refs[n] for n in values], list(values.values()))

    def get(self, names):
        return dict(zip(names, self.loaded.get_floats([self.refs[n] for n in names])))

    def vector(self, what: str, n: int | None = None):
        n = self.nx if n is None else n
        buffer = (ctypes.c_double * max(n, 1))()
        getattr(self.fmu, what)(buffer, n)
        return list(buffer[:n])

    def derivatives(self, n: int | None = None):
        n = self.nx if n is None else n
        buffer = (ctypes.c_double * max(n, 1))()
        self.loaded.get_derivatives(buffer, n)
        return list(buffer[:n])

    def states(self, values):
        buffer = (ctypes.c_double * len(values))(*values)
        self.fmu.setContinuousStates(buffer, len(values))

    def start(self):
        self.fmu.exitInitializationMode()
        self.settle()

    def event(self):
        self.fmu.enterEventMode()
        self.settle()

    def settle(self):
        while self.loaded.update_discrete_states()[0]:
            pass
        self.fmu.enterContinuousTimeMode()

    def close(self):
        self.loaded.close()

    def free(self):
        self.loaded.free()


@pytest.fixture(params=(2, 3), ids=("fmi2", "fmi3"))
def model(request, fmu_paths, fmu3_paths, tmp_path):
    """``model(name)``: a model-exchange instance in initialization mode, freed at the end."""
    made = []
    paths = fmu_paths if request.param == 2 else fmu3_paths

    def make(name):
        made.append(Model(paths[name], tmp_path / f"{name}_{len(made)}", name, []))
        return made[-1]

    yield make
    for instance in made:
        instance.free()


def _knowns(name: str) -> list:
    return [v.name for v in FMUS[name].inputs] + [s.variable.name for s in FMUS[name].states]


def _acting(instance, x: list, u: list, evaluate) -> tuple:
    """Projection parameters and a state near ``x`` at which the projection acts on all four estimates: the
    gradient rates (``none``) at the point show where each estimate's rate points (they do not depend on the
    estimate itself, so a weight vector turned round turns its outward rate round)."""
    spec = FMUS["DSCController"]
    rates = dict(zip((s.variable.name for s in spec.states), evaluate(x, u, derivatives_only=True)))
    x = list(x)
    names = [s.variable.name for s in spec.states]
    parameters = {"W1_max": 0.1, "W2_max": 0.1}
    for name in ("a1", "a2"):
        value, rate = x[names.index(f"{name}_hat")], rates[f"{name}_hat"]
        low, high = (value - 10.0, value - 0.01) if rate > 0 else (value + 0.01, value + 10.0)
        parameters.update({f"{name}_min": low, f"{name}_max": high, f"{name}_hat0": min(max(0.0, low), high)})
    for name, count in (("W1", 8), ("W2", 6)):
        entries = [names.index(f"{name}_hat_{i}") for i in range(1, count + 1)]
        if sum(x[i] * rates[f"{name}_hat_{k}"] for k, i in enumerate(entries, start=1)) < 0:
            for i in entries:
                x[i] = -x[i]
    return parameters, x


@pytest.mark.parametrize("name", NAMES)
def test_the_declared_dependencies_are_the_ones_the_fmu_has(model, name):
    """Every output and derivative changes with exactly the inputs and states ModelStructure declares:
    each known changed in turn at a point away from any special value, through the FMU's binary; for the
    controller under each adaptation law (the projection acting on all four estimates), whose union
    ModelStructure declares."""
    spec = FMUS[name]
    inputs = [v.name for v in spec.inputs]
    rng = np.random.default_rng(7)
    x = list(rng.uniform(0.5, 2.0, len(spec.states)))
    u = list(rng.uniform(0.5, 2.0, len(inputs)))
    outputs = [v.name for v in spec.outputs]
    laws = [None] if name != "DSCController" else [*range(len(P.ADAPTATIONS))]
    found = {}
    for law in laws:
        instance = model(name)
        instance.set({n: CONTROLLER_START.get(n, 1.0) + 0.3 for n in inputs})

        def evaluate(x, u, derivatives_only=False):
            instance.fmu.setTime(0.7)
            instance.states(x)
            if inputs:
                instance.set(dict(zip(inputs, u)))
            derivatives = dict(zip((s.derivative.name for s in spec.states), instance.derivatives()))
            return list(derivatives.values()) if derivatives_only else {**instance.get(outputs), **derivatives}

        point = x
        if law is not None:
            if law == P.ADAPTATIONS.index("projection"):
                probe = model(name)
                probe.loaded.set_integers([probe.refs["adaptation"]], [P.ADAPTATIONS.index("none")])
                probe.start()
                parameters, point = _acting(probe, x, u, lambda x, u, derivatives_only: _rates(probe, x, u, inputs))
                instance.set(parameters)
            instance.loaded.set_integers([instance.refs["adaptation"]], [law])
        instance.start()
        evaluate(point, u)
        instance.event()  # the switches chosen at the point
        base = evaluate(point, u)
        for unknown in base:
            found.setdefault(unknown, set())
        for i, known in enumerate(_knowns(name)):
            changed_x, changed_u = list(point), list(u)
            if i < len(inputs):
                changed_u[i] *= 1.001
            else:
                changed_x[i - len(inputs)] *= 1.001
            after = evaluate(changed_x, changed_u)
            for unknown in base:
                if after[unknown] != base[unknown]:
                    found[unknown].add(known)
        if law == P.ADAPTATIONS.index("projection"):
            assert all(base[f"der({n})"] == 0.0 for n in ("a1_hat", "a2_hat"))  # the projection acts
    md = instance.md
    declared = {u.variable.name: {d.name for d in u.dependencies} - {"time"}
                for u in (*md.outputs, *md.derivatives) if u.variable.name in found}
    assert found == declared


def _rates(instance, x: list, u: list, inputs: list) -> list:
    """The state derivatives of ``instance`` at time 0.7, states ``x`` and inputs ``u``."""
    instance.fmu.setTime(0.7)
    instance.states(x)
    instance.set(dict(zip(inputs, u)))
    return instance.derivatives()


def test_the_plant_derivatives_are_equations_6_to_8(model):
    """Spot checks by hand: der(i1) depends on u1, omega1, i1 only (8); der(x) on theta, omega1, omega2 (6);
    der(omega1) on the currents, the wheel speeds and, through the disturbance torques, the time (7), which
    FMI 3.0 names."""
    instance = model("MobileRobot")
    md = instance.md
    depends = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.derivatives}
    assert depends["der(i1)"] == ["i1", "omega1", "u1"]
    assert depends["der(x)"] == ["omega1", "omega2", "theta"]
    time = ["time"] if instance.version == 3 else []
    assert depends["der(omega1)"] == sorted(["i1", "i2", "omega1", "omega2", *time])
    instance.free()


def test_the_filters_follow_the_inputs_until_initialization_ends(model):
    """docs/model.md §5.2: in initialization mode x2f = x2bar and x3f = x3bar of the inputs set, whatever
    was set before; from the end of initialization they are states of their own."""
    instance = model("DSCController")
    g = gains({v.name: v.start for v in P.CONTROLLER_PARAMETERS})
    names = [v.name for v in P.CONTROLLER_INPUTS]
    for shift in (0.0, 0.4):
        m = [CONTROLLER_START[n] + (shift if n == "x" else 0.0) for n in names]
        instance.set(dict(zip(names, m)))
        expected = start_filters(g, initial_controller_state({v.name: v.start for v in P.CONTROLLER_PARAMETERS}), m)
        assert instance.vector("getContinuousStates") == pytest.approx(expected, rel=1e-15, abs=1e-15)
        assert instance.derivatives()[2:4] == [0.0, 0.0]  # x2f_dot(0) = 0
    instance.fmu.exitInitializationMode()
    frozen = instance.vector("getContinuousStates")
    instance.set({"x": 9.0})
    assert instance.vector("getContinuousStates") == frozen
    instance.free()


def _heading(instance: Model, theta: float) -> dict:
    instance.set({"theta": theta})
    return {**instance.get(["S13", "wrap_indicator"]), "der(x2f1)": instance.derivatives()[2]}


def test_the_wrap_is_held_between_events_and_jumps_at_one(model):
    """docs/model.md §5.13: in continuous-time mode S13bar = thetar - theta - 2 pi turns with turns
    held, so S13 and the filter's derivative stay continuous as thetar - theta crosses pi while the
    wrap indicator changes sign; the event then wraps S13bar as the law does (co-simulation's value),
    a jump of 2 pi."""
    instance = model("DSCController")
    instance.start()
    g = gains({v.name: v.start for v in P.CONTROLLER_PARAMETERS})
    x = instance.vector("getContinuousStates")
    before = _heading(instance, -math.pi + 1e-3)  # theta_r = 0: thetar - theta just below pi
    after = _heading(instance, -math.pi - 1e-3)  # just above pi: the wrap would jump
    assert before["wrap_indicator"] > 0 > after["wrap_indicator"]
    assert abs(after["S13"] - before["S13"]) < 1e-2  # continuous: a 2e-3 change of theta, no jump of 2 pi
    assert after["der(x2f1)"] == pytest.approx(before["der(x2f1)"], rel=0.05)
    instance.event()
    jumped = _heading(instance, -math.pi - 1e-3)
    m = [CONTROLLER_START[n] for n in CONTROLLER_START]
    m[2] = -math.pi - 1e-3
    law = control_law(g, x, m)
    assert jumped["S13"] == pytest.approx(law.S13, rel=1e-12)
    assert jumped["der(x2f1)"] == pytest.approx(law.derivative[2], rel=1e-12)
    assert after["S13"] - jumped["S13"] == pytest.approx(2 * math.pi, rel=1e-12)
    instance.close()


def test_the_beta_guard_changes_only_at_events(model):
    """beta_guard_active and the law's division stay as chosen at the last event while beta crosses
    beta_min in continuous-time mode; the guard indicator shows the crossing; the event switches and
    counts it (docs/model.md §5.6, §5.13)."""
    instance = model("DSCController")
    instance.start()
    refs = [instance.refs[n] for n in ("beta_guard_active", "beta_guard_count")]
    ahead = {"x": 6.0, "y": 2.0, "theta": 0.0}  # the robot ahead of the reference: S11 < 0, beta < 0
    instance.set(ahead)
    assert instance.get(["guard_indicator"])["guard_indicator"] < 0
    assert instance.fmu.getBoolean(refs[:1]) == [False]
    instance.event()
    assert instance.fmu.getBoolean(refs[:1]) == [True]
    assert instance.loaded.get_integers(refs[1:]) == [1]
    instance.close()


def test_model_exchange_refuses_what_is_not_a_state_and_discards_refused_values(model):
    instance = model("ReferenceRobot")
    instance.start()
    with pytest.raises(FMICallException, match="status 2"):  # discard: the solver may try again
        instance.states([math.nan, 0.0, 0.0])
    assert instance.vector("getContinuousStates") == [2.0, 2.0, 0.0]
    instance.free()
    controller = model("DSCController")
    controller.set({"v_r": -1.0})  # refused (Assumption 2); the last valid value is kept
    controller.start()
    with pytest.raises(FMICallException, match="status 2"):
        controller.derivatives()
    controller.set({"v_r": 1.0})
    assert all(math.isfinite(v) for v in controller.derivatives())
    with pytest.raises(FMICallException, match="status 3"):
        controller.derivatives(19)
    controller.free()


def test_an_fmu_state_restores_the_held_switches(model):
    """An FMU state taken before the guard engaged brings back the switches held then."""
    instance = model("DSCController")
    instance.start()
    state = instance.fmu.getFMUState()
    active = [instance.refs["beta_guard_active"]]
    ahead = {"x": 6.0, "y": 2.0, "theta": 0.3}  # beta < beta_min, S13 != 0: the guard changes h2
    instance.set(ahead)
    unguarded = instance.derivatives()
    instance.event()
    guarded = instance.derivatives()
    assert instance.fmu.getBoolean(active) == [True] and guarded != unguarded
    instance.fmu.setFMUState(state)
    instance.set(ahead)
    assert instance.fmu.getBoolean(active) == [False]
    assert instance.derivatives() == unguarded
    instance.close()


@pytest.mark.slow
@pytest.mark.parametrize("version", (2, 3))
def test_the_closed_loop_through_model_exchange_is_the_reference_solution(fmu_paths, fmu3_paths, version):
    """The three FMUs as one ODE (outputs to inputs at every evaluation): no coupling error, so at a
    tight tolerance the position is the monolithic reference solution's to 1e-5 m over the paper's 30 s."""
    paths = fmu_paths if version == 2 else fmu3_paths
    scenario = load_scenario("paper")
    run = simulate_model_exchange(scenario, paths, tolerance=1e-8)
    reference = reference_solution(scenario)
    assert np.array_equal(run.result["time"], reference["time"])
    deviation = np.hypot(run.result["x"] - reference["x"], run.result["y"] - reference["y"])
    assert deviation.max() < 1e-5
    assert run.settings["interface"] == "model-exchange" and run.settings["events"] == 0


@pytest.mark.slow
def test_the_guard_crossings_of_figure_eight_are_events(fmu_paths):
    """figure_eight crosses beta = beta_min (docs/model.md §5.13): the solver stops at each crossing, the
    guard engages as often as the reference solution's beta falls below beta_min, and the run stays
    with the reference solution."""
    scenario = load_scenario("figure_eight")
    run = simulate_model_exchange(scenario, fmu_paths, tolerance=1e-8)
    reference = reference_solution(scenario)
    below = reference["beta"] < scenario.parameters("DSCController")["beta_min"]
    engagements = int(np.sum(below[1:] & ~below[:-1]) + below[0])
    assert run.result["beta_guard_count"][-1] == engagements > 0
    assert run.settings["events"] >= 2 * engagements - 1
    deviation = np.hypot(run.result["x"] - reference["x"], run.result["y"] - reference["y"])
    assert deviation.max() < 1e-5


def test_a_state_of_the_other_interface_is_refused(fmu_paths, tmp_path):
    """A serialized FMU state taken in co-simulation's step mode cannot become a model-exchange
    instance's state (nor the other way): fmi2Error naming both."""
    from fmpy.fmi2 import FMU2Slave

    path = fmu_paths["ReferenceRobot"]
    md = read_model_description(str(path))
    folder = extract(str(path), unzipdir=tmp_path / "fmu")
    slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier="ReferenceRobot", instanceName="cs")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    data = slave.serializeFMUstate(slave.getFMUstate())
    slave.terminate()
    slave.freeInstance()
    log = []
    instance = Model(path, tmp_path / "me", "ReferenceRobot", log)
    state = instance.fmu.deSerializeFMUstate(data)
    with pytest.raises(FMICallException, match="status 3"):
        instance.fmu.setFMUstate(state)
    assert any("the FMU state is one of co-simulation, in state step mode; this instance is for model exchange"
               in m.message for m in log)
    instance.free()
