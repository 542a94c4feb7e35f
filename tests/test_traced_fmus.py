"""The FMUs with the C traced from their models (docs/traced-c.md) against the same FMUs running their models in
Python (the parameter ``traced`` = off, or built with ``--no-traced``): the same bits on every route, through the
fallbacks to Python and back, with FMU states and a switch of the parameter mid-run; the Jacobians too; what the
binaries import and what the build names as not traced."""

import ctypes
import json
import re
import sys
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Model, FMU2Slave

from c_hosts import compile_c, parse_rows, run_c, write_plan
from elf_symbols import imported_functions
from dsc_fmu import cosimulate, load_scenario
from dsc_fmu.cosim.model_exchange import linearise_at, simulate_model_exchange
from dsc_fmu.fmubuild.binary import LINUX
from dsc_fmu.fmubuild.traced_models import fmu_source
from dsc_fmu.identity import BUILD_ID_FILE
from dsc_fmu.models.parameters import TRACED
from dsc_fmu.platforms import library_path
from dsc_fmu.registry import ORDER

ON, OFF = TRACED.index("on"), TRACED.index("off")


def traced(scenario, value: int):
    """``scenario`` with the parameter ``traced`` = ``value`` in all three FMUs."""
    return replace(scenario, **{part: {**getattr(scenario, part), "traced": value}
                                for part in ("plant", "controller", "reference")})


def assert_same_bits(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype and len(a) == len(b)
    differing = [name for name in a.dtype.names if a[name].tobytes() != b[name].tobytes()]
    assert not differing, {name: int(np.flatnonzero(a[name] != b[name])[0]) for name in differing}


def both(run, scenario, fmus, **settings):
    """``run`` of ``scenario`` with the traced C and in Python."""
    return [run(traced(scenario, value), fmus, **settings) for value in (ON, OFF)]


@pytest.mark.slow
@pytest.mark.parametrize("name, version, settings", [
    ("paper", 2, {}),
    ("paper", 3, {"stop_time": 10.0}),
    ("paper", 2, {"coupling": "linear", "step_size": 0.01}),
    ("paper", 3, {"order": "jacobi", "coupling": "linear", "step_size": 0.005}),
    ("paper", 2, {"input_derivatives": True, "coupling": "linear", "stop_time": 5.0}),
    ("robustness", 2, {"stop_time": 15.0}),
    ("robustness", 3, {"stop_time": 15.0, "step_size": 0.004}),
    ("figure_eight", 2, {"stop_time": 15.0}),
], ids=["paper-2", "paper-3", "linear-2", "jacobi-3", "input-derivatives-2", "robustness-2", "robustness-3",
        "figure-eight-2"])
def test_co_simulation_gives_the_bits_of_python(fmu_paths, fmu3_paths, name, version, settings):
    """The project's master on fmpy: every recorded signal and every message the same with the traced C and in
    Python. The runs cover the fallbacks: the robustness scenario's drivers limit and the projection acts, the
    figure eight's beta guard acts (each such step runs in Python), input derivatives run every step in Python."""
    fmus = fmu3_paths if version == 3 else fmu_paths
    fast, python = both(cosimulate, load_scenario(name), fmus, **settings)
    assert_same_bits(fast.result, python.result)
    if name == "robustness":
        assert fast.result["saturation_time"][-1] > 4.0 and fast.result["saturation_count"][-1] >= 5
    if name == "figure_eight":
        assert fast.result["beta_guard_count"][-1] > 500
    assert [(m.fmu, m.status, m.message) for m in fast.log] == [(m.fmu, m.status, m.message) for m in python.log]
    assert fast.steps == python.steps


@pytest.mark.slow
@pytest.mark.parametrize("name, version, method, stop", [("paper", 2, "DOP853", 5.0), ("robustness", 3, "BDF", 12.0)])
def test_model_exchange_and_its_jacobians_give_the_bits_of_python(fmu_paths, fmu3_paths, name, version, method, stop):
    """The three FMUs as one ODE (derivatives, event indicators, events; BDF asks for the loop's Jacobian from the
    directional derivatives) and the closed loop linearised at 2 s: the same bits with the traced C and in Python."""
    fmus = fmu3_paths if version == 3 else fmu_paths
    scenario = load_scenario(name)
    fast, python = both(simulate_model_exchange, scenario, fmus, stop_time=stop, method=method)
    assert_same_bits(fast.result, python.result)
    linear = [linearise_at(traced(scenario, value), fmus, 2.0) for value in (ON, OFF)]
    for matrix in "ABCD":
        assert getattr(linear[0], matrix).tobytes() == getattr(linear[1], matrix).tobytes(), matrix


@pytest.mark.slow
def test_the_c_master_gives_the_bits_of_fmus_built_without_the_traced_c(fmu_paths, untraced_fmu_paths, tmp_path):
    """The paper's loop in C (no Python in the process's loop), Gauss-Seidel and Jacobi on threads: the FMUs as built
    and built with ``--no-traced`` give the same rows."""
    master = compile_c("c_master.c", tmp_path / "c_master")
    record = {"ReferenceRobot": ["x_r", "y_r", "theta_r", "v_r"],
              "MobileRobot": ["x", "y", "theta", "omega1", "i2", "u1_applied", "saturation_time"],
              "DSCController": ["u1", "u2", "S13", "beta", "a1_hat", "W2_hat_norm"]}
    rows = {}
    for label, paths in (("traced", fmu_paths), ("python", untraced_fmu_paths)):
        unzipped = {n: Path(extract(str(p), unzipdir=tmp_path / label / n)) for n, p in paths.items()}
        for order, threads in (("gauss-seidel", False), ("jacobi", True)):
            plan = write_plan(tmp_path / label / f"{order}.txt", unzipped, 5000, 1e-3, order, threads, 50, record)
            run = run_c([master, plan], tmp_path)
            assert run.returncode == 0, run.stderr
            rows[label, order] = parse_rows(run.stdout)
    for order in ("gauss-seidel", "jacobi"):
        assert np.array(rows["traced", order]).tobytes() == np.array(rows["python", order]).tobytes()
        assert len(rows["traced", order]) == 101


def slave(fmu_unzipped, name: str, instance: str) -> tuple:
    """An initialized FMI 2.0 co-simulation instance of ``name`` and the value references by name."""
    folder = fmu_unzipped[name]
    md = read_model_description(folder)
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=name, instanceName=instance,
                    libraryPath=library_path(folder, 2, name))
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu, {v.name: v.valueReference for v in md.modelVariables}


def model_exchange(fmu_unzipped, name: str, instance: str, value: int) -> tuple:
    """An FMI 2.0 model-exchange instance of ``name`` with ``traced`` = ``value``, in continuous-time mode; its model
    description and value references by name."""
    folder = fmu_unzipped[name]
    md = read_model_description(folder)
    refs = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Model(guid=md.guid, unzipDirectory=folder, modelIdentifier=name, instanceName=instance,
                    libraryPath=library_path(folder, 2, name))
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setInteger([refs["traced"]], [value])
    fmu.exitInitializationMode()
    fmu.newDiscreteStates()
    fmu.enterContinuousTimeMode()
    return fmu, md, refs


def drive(fmu, refs, steps: range, switch=None, voltages=(6.0, -4.0)) -> list:
    """Step the plant with ramping voltages; at each step in ``switch`` (step -> traced value) set the parameter
    first. The outputs after each step."""
    outputs = [refs[n] for n in ("x", "y", "theta", "omega1", "omega2", "i1", "i2", "u1_applied")]
    rows = []
    for k in steps:
        if switch and k in switch:
            fmu.setInteger([refs["traced"]], [switch[k]])
        fmu.setReal([refs["u1"], refs["u2"]], [voltages[0] + 0.01 * k, voltages[1] - 0.02 * k])
        fmu.doStep(k * 1e-3, 1e-3)
        rows.append(fmu.getReal(outputs))
    return rows


def test_switching_the_parameter_mid_run_and_fmu_states_keep_the_bits(fmu_unzipped):
    """The plant stepped in C, switched to Python and back mid-run (``traced`` is tunable), its FMU state taken
    while the C is ahead of the slave and set again: the same outputs as a run in Python throughout."""
    python, refs = slave(fmu_unzipped, "MobileRobot", "python")
    python.setInteger([refs["traced"]], [OFF])
    expected = drive(python, refs, range(300))
    mixed, _ = slave(fmu_unzipped, "MobileRobot", "mixed")
    first = drive(mixed, refs, range(100), {60: OFF, 80: ON})
    state = mixed.getFMUState()
    drive(mixed, refs, range(100, 200))
    mixed.setFMUState(state)
    assert first + drive(mixed, refs, range(100, 300), {250: OFF}) == expected
    for fmu in (python, mixed):
        fmu.terminate()
        fmu.freeInstance()


def test_a_value_refused_between_steps_in_c_is_refused_by_the_slave_as_before(fmu_unzipped):
    """After steps in C, an input the slave's check refuses (the controller's v_r must be > 0) goes to Python: the
    same message; a valid value after it, and the run goes on as it does in Python throughout; a step with the
    value refused is discarded."""
    runs = {}
    for value in (ON, OFF):
        fmu, refs = slave(fmu_unzipped, "DSCController", f"controller{value}")
        fmu.setInteger([refs["traced"]], [value])
        rows = []
        for k in range(40):
            if k in (20, 39):
                fmu.setReal([refs["v_r"]], [-1.0])
            if k == 20:
                fmu.setReal([refs["v_r"]], [0.5])
            fmu.setReal([refs["x_r"]], [2.5 + 0.01 * k])
            try:
                fmu.doStep(k * 1e-3, 1e-3)
            except Exception as error:  # fmpy raises on fmi2Discard
                rows.append(str(error))
                break
            rows.append(tuple(fmu.getReal([refs["u1"], refs["u2"], refs["a1_hat"]])))
        runs[value] = rows
        fmu.terminate()
        fmu.freeInstance()
    assert runs[ON] == runs[OFF]
    assert len(runs[ON]) == 40 and "discard" in runs[ON][-1]


def test_directional_derivatives_give_the_bits_of_python(fmu_unzipped):
    """Model exchange: the Jacobian of the state derivatives and the outputs by the states and inputs, column by
    column, at a point away from the start with the switches held; the same bits with the traced C and in Python."""
    for name in ORDER:
        columns = {}
        for value in (ON, OFF):
            fmu, md, refs = model_exchange(fmu_unzipped, name, f"{name}{value}", value)
            unknowns = [d.variable.valueReference for d in md.derivatives]
            unknowns += [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
            knowns = [d.variable.derivative.valueReference for d in md.derivatives]
            knowns += [v.valueReference for v in md.modelVariables if v.causality == "input"]
            fmu.setTime(0.7)
            x = [0.1 * (i + 1) for i in range(len(md.derivatives))]
            fmu.setReal(knowns[:len(x)], x)
            columns[value] = [fmu.getDirectionalDerivative(unknowns, [known], [1.5]) for known in knowns]
            columns[value].append(fmu.getDirectionalDerivative(unknowns, knowns, [0.25 * k for k in range(len(knowns))]))
            fmu.terminate()
            fmu.freeInstance()
        assert np.array(columns[ON]).tobytes() == np.array(columns[OFF]).tobytes(), name


def test_the_binaries_take_their_math_from_the_c_library(fmu_paths, tmp_path):
    """At -O0 Zig would link its own sin, one unit in the last place off CPython's (docs/traced-c.md): each Linux
    binary imports from the C library every one of sin, cos, atan, fmod and sqrt that its traced C calls."""
    for name, path in fmu_paths.items():
        with zipfile.ZipFile(path) as fmu:
            library = tmp_path / f"{name}.so"
            library.write_bytes(fmu.read(LINUX.file(2, name)))
        called = set(re.findall(r"\b(sin|cos|atan|fmod|sqrt)\(", fmu_source(name)[0]))
        assert "sin" in called and called <= imported_functions(library), (name, called)


def test_the_build_names_what_is_not_traced(fmu_paths, untraced_fmu_paths):
    """The build record: the controller's step under discretization = euler is not traced (one Euler step, not RK4
    sub-steps), per adaptation law and coupling, each with its reason; the others trace everything; built with
    ``--no-traced``, none is."""
    records = {}
    for label, paths in (("traced", fmu_paths), ("python", untraced_fmu_paths)):
        for name, path in paths.items():
            with zipfile.ZipFile(path) as fmu:
                records[label, name] = json.loads(fmu.read(BUILD_ID_FILE))["traced"]
    untraceable = records["traced", "DSCController"]["untraceable"]
    assert sorted(untraceable) == sorted(f"dsc_controller_rk4{line}__adaptation_{law}__discretization_euler"
                                         for line in ("", "_line") for law in ("sigma", "e", "projection", "none"))
    assert all("discretization = euler takes one Euler step" in reason for reason in untraceable.values())
    assert records["traced", "MobileRobot"] == records["traced", "ReferenceRobot"] == {"untraceable": {}}
    assert all(records["python", name] is None for name in ORDER)


def calls_into(folder, action) -> list:
    """The functions of the FMU extracted in ``folder`` that Python runs during ``action`` (a profile hook: the
    binary runs the slave in this process's CPython, on this thread)."""
    called = []

    def profile(frame, event, argument):
        if event == "call" and frame.f_code.co_filename.startswith(str(folder)):
            called.append(frame.f_code.co_name)

    sys.setprofile(profile)
    try:
        action()
    finally:
        sys.setprofile(None)
    return called


@pytest.mark.parametrize("value", (ON, OFF))
def test_between_calls_into_python_the_traced_path_runs_without_python(fmu_unzipped, value):
    """Once the first step has run in Python, the plant's inputs set, steps taken and outputs read enter no Python
    but for what the slave needs (the parameter off: all of it); in model exchange the derivatives, event indicators
    and a Jacobian column neither, until an event."""
    fmu, refs = slave(fmu_unzipped, "MobileRobot", f"quiet{value}")
    fmu.setInteger([refs["traced"]], [value])
    drive(fmu, refs, range(1))
    called = calls_into(fmu_unzipped["MobileRobot"], lambda: drive(fmu, refs, range(1, 50)))
    assert not called if value == ON else called.count("do_step") == 49
    fmu.terminate()
    fmu.freeInstance()
    model, md, refs = model_exchange(fmu_unzipped, "DSCController", f"me{value}", value)
    n = len(md.derivatives)
    x, dx, z = (ctypes.c_double * n)(), (ctypes.c_double * n)(), (ctypes.c_double * md.numberOfEventIndicators)()
    model.getContinuousStates(x, n)
    derivatives = [d.variable.valueReference for d in md.derivatives]

    def evaluate():
        for k in range(20):
            model.setTime(k * 1e-3)
            x[0] += 1e-6
            model.setContinuousStates(x, n)
            model.getDerivatives(dx, n)
            model.getEventIndicators(z, md.numberOfEventIndicators)
            model.getDirectionalDerivative(derivatives, [refs["x"]], [1.0])
            model.getReal([refs["u1"], refs["S13"]])

    called = calls_into(fmu_unzipped["DSCController"], evaluate)
    assert not called if value == ON else called.count("get_derivatives") == 20
    model.terminate()
    model.freeInstance()
