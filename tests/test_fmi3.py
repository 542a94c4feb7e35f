"""The FMI 3.0 FMUs (pythonfmu3): the same interface, behaviour and results as the FMI 2.0 ones.

Expectations come from the FMI 2.0 FMUs built from the same model code, the variable tables and
the FMI 3.0 standard; the co-simulation through the FMI 3.0 FMUs must equal the FMI 2.0 one.
"""

import json
import math
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu

from dsc_fmu.errors import FmiVersionError
from dsc_fmu.fmubuild.fmus import (
    DEFAULT_FMU_DIR, build_fmu, build_fmus, current_fmus, default_fmu_dir, ensure_fmus, resolve_fmu_dir, source_hash,
)
from dsc_fmu.fmubuild.model_description import UNITS
from dsc_fmu.identity import BUILD_ID_FILE, fmu_build_id
from dsc_fmu.registry import FMUS
from dsc_fmu.cosim.master import Cosimulator, cosimulate
from dsc_fmu.models import parameters as P
from dsc_fmu.scenario import load_scenario
from isolation import bits, run_isolated, violations

REPO = Path(__file__).resolve().parents[1]
NAMES = tuple(FMUS)
TYPES = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean"}  # FMI 2.0 type -> FMI 3.0 type
FMI3_OK, FMI3_WARNING, FMI3_DISCARD, FMI3_ERROR, FMI3_FATAL = range(5)


@pytest.fixture(scope="module")
def md3(fmu3_paths):
    return {name: read_model_description(str(path)) for name, path in fmu3_paths.items()}


@pytest.fixture(scope="module")
def md2(fmu_paths):
    return {name: read_model_description(str(path)) for name, path in fmu_paths.items()}


class Instance:
    """An fmpy FMU3Slave with value references by name and its log messages."""

    def __init__(self, path, tmp_path, name):
        self.md = read_model_description(str(path))
        self.folder = extract(str(path), unzipdir=tmp_path / name)
        self.log = []
        self.fmu = FMU3Slave(guid=self.md.guid, unzipDirectory=self.folder,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(loggingOn=True, logMessage=lambda env, status, category, message:
                             self.log.append((status, message.decode())))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}

    def get(self, *names):
        return self.fmu.getFloat64([self.vr[n] for n in names])

    def set(self, **values):
        self.fmu.setFloat64([self.vr[n] for n in values], list(values.values()))


# --- build and model description ------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_fmi3_fmu_validates_without_problems(fmu3_paths, md3, name):
    assert md3[name].fmiVersion == "3.0"
    assert validate_fmu(str(fmu3_paths[name])) == []


@pytest.mark.parametrize("name", NAMES)
def test_fmi3_interface_equals_fmi2(md2, md3, name):
    """Same names in the same order, types, causality, variability, initial, start, unit, range,
    descriptions; FMI 3.0 adds only the independent variable ``time`` (s)."""
    new = md3[name].modelVariables
    assert [(v.name, v.causality, v.variability, v.unit) for v in new if v.causality == "independent"] == [
        ("time", "independent", "continuous", "s")]
    new = [v for v in new if v.causality != "independent"]
    old = md2[name].modelVariables
    assert [v.name for v in new] == [v.name for v in old]
    for a, b in zip(old, new):
        assert b.type == TYPES[a.type], a.name
        assert (b.causality, b.variability, b.initial, b.unit, b.min, b.max, b.description) == (
            a.causality, a.variability, a.initial, a.unit, a.min, a.max, a.description), a.name
        if a.start is None:
            assert b.start is None, a.name
        else:
            assert float(b.start) == float(a.start), a.name
    assert len({v.valueReference for v in md3[name].modelVariables}) == len(md3[name].modelVariables)


@pytest.mark.parametrize("name", NAMES)
def test_fmi3_starts_units_and_experiment_come_from_the_tables(md3, name):
    md = md3[name]
    spec = FMUS[name]
    variables = {v.name: v for v in md.modelVariables}
    for v in (*spec.parameters, *spec.inputs):
        assert float(variables[v.name].start) == v.start, v.name  # exact: written with repr
    for v in (*spec.parameters, *spec.inputs, *spec.outputs):
        assert variables[v.name].unit == (None if v.integer else v.unit), v.name
        assert variables[v.name].description == v.description
    definitions = {u.name: u.baseUnit for u in md.unitDefinitions}
    for unit in {v.unit for v in md.modelVariables if v.unit}:
        base = definitions[unit]
        exponents = {k: getattr(base, k) for k in ("kg", "m", "s", "A", "rad") if getattr(base, k)} if base else {}
        assert exponents == UNITS[unit], unit
    assert (md.defaultExperiment.startTime, md.defaultExperiment.stopTime, md.defaultExperiment.stepSize) == (
        "0.0", "30.0", "0.001")
    cs = md.coSimulation
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate and cs.canHandleVariableCommunicationStepSize
    assert md.description


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_default_experiment_declares_the_model_exchange_tolerance(md2, md3, version, name):
    """Every model description's DefaultExperiment carries the relative tolerance the project's model-exchange
    runs are measured at (importers such as FMI Library warn where it is missing), as fmpy reads it."""
    experiment = (md3 if version == 3 else md2)[name].defaultExperiment
    assert float(experiment.tolerance) == P.DEFAULT_TOLERANCE


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_model_structure_declares_the_real_dependencies(md2, md3, version, name):
    md = (md2 if version == 2 else md3)[name]
    outputs = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs}
    assert list(outputs) == [v.name for v in md.modelVariables if v.causality == "output"]
    states = {s.variable.name for s in FMUS[name].states}
    unknowns = {*outputs, *states, *(s.derivative.name for s in FMUS[name].states)}
    assert [u.variable.name for u in md.initialUnknowns] == [v.name for v in md.modelVariables if v.name in unknowns]
    inputs = {v.name for v in FMUS[name].inputs}
    if name != "DSCController":  # no direct feedthrough but the plant's drivers (docs/model.md §5.14)
        fed = {output: sorted(inputs.intersection(depends)) for output, depends in outputs.items()
               if not inputs.isdisjoint(depends)}
        assert fed == ({"u1_applied": ["u1"], "u2_applied": ["u2"], "saturation_active": ["u1", "u2"]}
                       if name == "MobileRobot" else {})
    else:
        assert sorted(inputs.intersection(outputs["u1"])) == sorted(inputs - {"i2"})
        assert sorted(inputs.intersection(outputs["u2"])) == sorted(inputs - {"i1"})
        assert outputs["S11"] == sorted(("x", "y", "theta", "x_r", "y_r"))
        assert outputs["a1_hat"] == ["a1_hat"] and outputs["W2_hat_6"] == ["W2_hat_6"]  # states
        assert outputs["beta_guard_count"] == []


@pytest.mark.parametrize("name", NAMES)
def test_fmi3_bundled_modules_carry_a_name_unique_to_the_build(fmu3_paths, name):
    digest = source_hash(FMUS[name], 3)[:12]
    assert digest != source_hash(FMUS[name], 2)[:12]
    with zipfile.ZipFile(fmu3_paths[name]) as archive:
        module = archive.read("resources/slavemodule.txt").decode()
        files = archive.namelist()
        script = archive.read(f"resources/{module}.py").decode()
        build_id = json.loads(archive.read(BUILD_ID_FILE))
    assert module.endswith(digest) and "fmi3" in module
    package = f"resources/dsc_fmu_{name.lower()}_{digest}/"
    assert {f"{package}fmu/fmi3.py", f"{package}fmu/slave.py", f"{package}fmu/controller_model.py",
            f"{package}models/controller.py"} <= set(files)
    assert f"{package}fmu/fmi2.py" not in files  # an FMI 3.0 FMU never needs pythonfmu
    assert not any(f.startswith("resources/dsc_fmu/") or f.startswith("resources/pythonfmu/") for f in files)
    assert "from dsc_fmu." not in script
    assert build_id["fmi_version"] == 3 and fmu_build_id(fmu3_paths[name]) == source_hash(FMUS[name], 3)


def test_default_folders_and_versions():
    assert default_fmu_dir(2) == DEFAULT_FMU_DIR == Path("build") / "fmus"
    assert default_fmu_dir(3) == Path("build") / "fmus3"
    with pytest.raises(ValueError, match="fmi_version = 4 is not allowed; allowed: 2 or 3"):
        build_fmus("unused", fmi_version=4)


def test_ensure_fmi3_builds_then_reuses_and_keeps_versions_apart(tmp_path):
    first = ensure_fmus(tmp_path, fmi_version=3)
    files = {path.name: (path.read_bytes(), path.stat().st_mtime_ns) for path in sorted(tmp_path.iterdir())}
    assert ensure_fmus(tmp_path, fmi_version=3) == first
    assert ensure_fmus(tmp_path) == first  # the folder's version
    with current_fmus(tmp_path) as current:
        assert current == first
    refused = (f"fmi_version = 2 is not allowed for {tmp_path}, which holds FMI 3.0 FMUs (they would be replaced); "
               "allowed: 3, or another folder")
    for write in (lambda: ensure_fmus(tmp_path, fmi_version=2), lambda: build_fmus(tmp_path, fmi_version=2),
                  lambda: build_fmu(FMUS["MobileRobot"], tmp_path, fmi_version=2),
                  lambda: current_fmus(tmp_path, fmi_version=2).__enter__()):
        with pytest.raises(FmiVersionError) as refusal:
            write()
        assert str(refusal.value) == refused
    assert {path.name: (path.read_bytes(), path.stat().st_mtime_ns) for path in sorted(tmp_path.iterdir())} == files


@pytest.mark.parametrize("declared, message", [
    ("1.0", "{folder} holds FMI 1.0 FMUs; allowed: a folder of FMI 2.0 or 3.0 FMUs, or one without FMUs"),
    ("2.0", None),
])
def test_a_folder_is_read_by_the_fmi_version_its_fmus_declare(tmp_path, declared, message):
    """Whoever built them: the ``fmiVersion`` of each FMU's modelDescription.xml; a file that is no FMU
    counts as none."""
    with zipfile.ZipFile(tmp_path / "MobileRobot.fmu", "w") as fmu:
        fmu.writestr("modelDescription.xml", f'<fmiModelDescription fmiVersion="{declared}" modelName="M"/>')
    (tmp_path / "DSCController.fmu").write_text("not an FMU")
    if message is None:
        assert resolve_fmu_dir(tmp_path) == (tmp_path, 2)
        with pytest.raises(FmiVersionError, match="allowed: 2, or another folder"):
            resolve_fmu_dir(tmp_path, 3)
    else:
        with pytest.raises(FmiVersionError) as refusal:
            resolve_fmu_dir(tmp_path)
        assert str(refusal.value) == message.format(folder=tmp_path)
    assert resolve_fmu_dir(tmp_path / "empty") == (tmp_path / "empty", 2)
    assert resolve_fmu_dir(tmp_path / "empty", 3) == (tmp_path / "empty", 3)
    assert resolve_fmu_dir(None, 3) == (default_fmu_dir(3), 3)


def test_build_script_builds_fmi3(tmp_path):
    process = subprocess.run([sys.executable, "build_fmus.py", "--fmi-version", "3", "--out", str(tmp_path)],
                             cwd=REPO, capture_output=True, text=True)
    assert process.returncode == 0, process.stderr
    assert sorted(p.name for p in tmp_path.glob("*.fmu")) == sorted(f"{n}.fmu" for n in NAMES)
    assert all(read_model_description(str(tmp_path / f"{n}.fmu")).fmiVersion == "3.0" for n in NAMES)
    bad = subprocess.run([sys.executable, "build_fmus.py", "--fmi-version", "4"], cwd=REPO, capture_output=True, text=True)
    assert bad.returncode != 0 and "--fmi-version" in bad.stderr


# --- behaviour through fmpy's FMU3Slave ---------------------------------------------------------------


def test_refused_values_discard_steps_without_fatal(fmu3_paths, tmp_path):
    robot = Instance(fmu3_paths["MobileRobot"], tmp_path, "refusing")
    try:
        robot.fmu.enterInitializationMode(startTime=0.0)
        robot.set(max_step=-1.0)  # refused, not raised: the call returns OK
        assert robot.get("max_step") == [1e-3]
        robot.fmu.exitInitializationMode()
        with pytest.raises(FMICallException) as error:
            robot.fmu.doStep(0.0, 0.01)
        assert error.value.status == FMI3_DISCARD
        assert any(s == FMI3_ERROR and "max_step = -1.0" in m for s, m in robot.log)
        robot.set(max_step=1e-3, u1=float("nan"))
        with pytest.raises(FMICallException):
            robot.fmu.doStep(0.0, 0.01)
        assert any("u1 = nan is not finite" in m for _, m in robot.log)
        robot.set(u1=12.0)
        robot.fmu.doStep(0.0, 0.01)
        assert all(math.isfinite(v) for v in robot.get("x", "omega1", "i1"))
        assert not any(s == FMI3_FATAL for s, _ in robot.log)
        robot.fmu.terminate()
    finally:
        robot.fmu.freeInstance()


def test_state_get_set_and_serialisation_restore_the_run(fmu3_paths, tmp_path):
    ctl = Instance(fmu3_paths["DSCController"], tmp_path, "stateful")
    inputs = [v.name for v in P.CONTROLLER_INPUTS]
    measured = dict(zip(inputs, [2.5, 1.0, math.pi / 2, 0, 0, 0, 0, 0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]))
    try:
        ctl.fmu.enterInitializationMode(startTime=0.0)
        ctl.set(**measured)
        ctl.fmu.exitInitializationMode()
        ctl.fmu.doStep(0.0, 0.01)
        state = ctl.fmu.getFMUState()
        serialized = ctl.fmu.serializeFMUState(state)
        ctl.fmu.doStep(0.01, 0.01)
        after = ctl.get("u1", "u2", "a1_hat", "W2_hat_1")
        ctl.fmu.setFMUState(state)
        ctl.fmu.doStep(0.01, 0.01)
        assert ctl.get("u1", "u2", "a1_hat", "W2_hat_1") == after
        restored = ctl.fmu.deserializeFMUState(serialized)
        ctl.fmu.setFMUState(restored)
        ctl.fmu.doStep(0.01, 0.01)
        assert ctl.get("u1", "u2", "a1_hat", "W2_hat_1") == after
        ctl.fmu.freeFMUState(state)
        ctl.fmu.freeFMUState(restored)
        ctl.fmu.terminate()
    finally:
        ctl.fmu.freeInstance()


def test_a_failing_step_is_discarded_and_the_state_api_rolls_back(fmu3_paths, tmp_path):
    """A step that fails inside the model (a fixed parameter within its range on which the state
    overflows) is an fmi3Discard, never fmi3Fatal; the FMU state API rolls the instance back to
    initialisation and it steps on."""
    robot = Instance(fmu3_paths["MobileRobot"], tmp_path, "raising")
    try:
        robot.fmu.enterInitializationMode(startTime=0.0)
        saved = robot.fmu.getFMUState()
        robot.set(La1=1e-320, u1=12.0)  # allowed (> 0), but u1 / La1 overflows
        robot.fmu.exitInitializationMode()
        with pytest.raises(FMICallException) as error:
            robot.fmu.doStep(0.0, 0.01)
        assert error.value.status == FMI3_DISCARD
        assert not any(s == FMI3_FATAL for s, _ in robot.log)
        robot.fmu.setFMUState(saved)
        robot.fmu.exitInitializationMode()
        robot.fmu.doStep(0.0, 0.01)
        assert all(math.isfinite(v) for v in robot.get("x", "omega1", "i1"))
        robot.fmu.freeFMUState(saved)
        robot.fmu.terminate()
    finally:
        robot.fmu.freeInstance()


# --- co-simulation: FMI 3.0 equals FMI 2.0 ------------------------------------------------------------


def _assert_same_run(a, b):
    assert a.result.dtype == b.result.dtype and len(a.result) == len(b.result)
    for column in a.result.dtype.names:
        np.testing.assert_allclose(b.result[column], a.result[column], rtol=1e-12, atol=1e-12, err_msg=column)


@pytest.mark.parametrize("order", ("gauss-seidel", "jacobi"))
def test_paper_scenario_through_fmi3_equals_fmi2(fmu_paths, fmu3_paths, order):
    scenario = load_scenario("paper")
    fmi2 = cosimulate(scenario, fmu_paths, stop_time=3.0, order=order)
    fmi3 = cosimulate(scenario, fmu3_paths, stop_time=3.0, order=order)
    _assert_same_run(fmi2, fmi3)
    assert fmi3.steps == 3000 and fmi3.result["time"][-1] == 3.0
    assert fmi3.result["position_error"][-1] < fmi3.result["position_error"][0]


def test_guard_and_reset_through_fmi3_equal_fmi2(fmu_paths, fmu3_paths):
    """The beta guard (Integer and Boolean outputs, warnings) and repeated runs after fmi3Reset."""
    scenario = load_scenario("ahead_start")
    fmi2 = cosimulate(scenario, fmu_paths, stop_time=0.5, step_size=1e-3)
    with Cosimulator(fmu3_paths) as simulator:
        first = simulator.run(scenario, stop_time=0.5, step_size=1e-3)
        second = simulator.run(scenario, stop_time=0.5, step_size=1e-3)
    _assert_same_run(fmi2, first)
    _assert_same_run(first, second)
    assert first.result["beta_guard_count"][-1] > 0
    assert any(m.fmu == "DSCController" and m.status == "WARNING" and "beta" in m.message for m in first.log)


def test_fmi2_and_fmi3_fmus_mix_in_one_run(fmu_paths, fmu3_paths):
    scenario = load_scenario("paper")
    mixed = {**fmu_paths, "DSCController": fmu3_paths["DSCController"]}
    _assert_same_run(cosimulate(scenario, fmu_paths, stop_time=0.5), cosimulate(scenario, mixed, stop_time=0.5))


ISOLATED = textwrap.dedent('''
    unzipped = driver.extract(config["fmu"], config["workdir"])
    fmu = driver.Fmi3Slave(unzipped, config["instance"])
    fmu.instantiate(logging_on=True)
    fmu.enter_initialization_mode(0.0)
    if config["inputs"]:
        fmu.set_float64(list(config["inputs"]), list(config["inputs"].values()))
    fmu.exit_initialization_mode()
    rows, steps = [fmu.outputs()], []
    h = config["step_size"]
    for k in range(config["steps"]):
        steps.append(fmu.do_step(k * h, h))
        rows.append(fmu.outputs())
    fmu.terminate()
    alive = loaded_modules()
    fmu.free_instance()
    report({"rows": rows, "steps": steps, "messages": fmu.messages, "unzipped": os.path.realpath(str(unzipped)),
            "modules": alive, "modules_after_free": sorted(loaded_modules()), "path_after_free": list(sys.path)})
''')


@pytest.mark.parametrize("name", NAMES)
def test_fmi3_fmu_runs_on_its_own_bundled_code(fmu3_paths, tmp_path, name):
    """In ``python -I -S`` with numpy, dsc_fmu, fmpy and scipy blocked (and recorded), the ctypes driver
    ``fmi_ctypes.py`` runs the FMU on the pythonfmu3 and dsc_fmu copies inside it, with the same
    outputs, to the last bit, as fmpy's FMU3Slave here (see ``isolation.py``)."""
    inputs = {"MobileRobot": [12.0, 8.0],
              "DSCController": [2.5, 1.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]}
    inputs = dict(zip([v.name for v in FMUS[name].inputs], inputs.get(name, [])))
    h, n = 0.01, 10
    config = dict(fmu=str(fmu3_paths[name]), workdir=str(tmp_path / "unzipped"), instance=f"{name}_isolated",
                  inputs=inputs, step_size=h, steps=n)
    result = run_isolated(ISOLATED, config, tmp_path)

    assert violations(result, f"dsc_fmu_{name.lower()}_") == {}
    assert [m for m in result["messages"] if m[0] > FMI3_WARNING] == []

    md = read_model_description(str(fmu3_paths[name]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outputs = {kind: [v.name for v in md.modelVariables if v.causality == "output" and v.type == kind]
               for kind in ("Float64", "Int32", "Boolean")}
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(fmu3_paths[name]), unzipdir=tmp_path / "fmpy"),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="fmpy_reference")
    getters = {"Float64": fmu.getFloat64, "Int32": fmu.getInt32, "Boolean": fmu.getBoolean}

    def read():
        return {m: v for kind, names in outputs.items() if names
                for m, v in zip(names, getters[kind]([vr[m] for m in names]))}

    fmu.instantiate(loggingOn=True, logMessage=lambda *args: None)
    try:
        fmu.enterInitializationMode(startTime=0.0)
        if inputs:
            fmu.setFloat64([vr[m] for m in inputs], list(inputs.values()))
        fmu.exitInitializationMode()
        rows, steps = [read()], []
        for k in range(n):
            steps.append(list(fmu.doStep(k * h, h)))
            rows.append(read())
        fmu.terminate()
    finally:
        fmu.freeInstance()

    assert list(result["rows"][0]) == list(rows[0])  # the driver finds fmpy's outputs, in fmpy's order
    assert all(math.isfinite(v) for row in result["rows"] for v in row.values())
    assert bits(result["rows"]) == bits(rows)
    assert result["steps"] == steps == [[False, False, False, k * h + h] for k in range(n)]
    assert result["rows"][0] != result["rows"][-1]


FMI3_MODEL_EXCHANGE_ATTRIBUTES = {
    "modelIdentifier", "needsExecutionTool", "canBeInstantiatedOnlyOncePerProcess", "canGetAndSetFMUState",
    "canSerializeFMUState", "providesDirectionalDerivatives", "providesAdjointDerivatives",
    "providesPerElementDependencies", "providesEvaluateDiscreteStates", "needsCompletedIntegratorStep",
}


@pytest.mark.parametrize("name", NAMES)
def test_fmi3_model_exchange_is_declared_with_fmi3_names(fmu3_paths, name):
    """FMI 3.0.2's fmi3ModelExchange attributes only (FMI Library reports any other as an error)."""
    with zipfile.ZipFile(fmu3_paths[name]) as fmu:
        root = ElementTree.fromstring(fmu.read("modelDescription.xml"))
    element = root.find("ModelExchange")
    assert set(element.attrib) <= FMI3_MODEL_EXCHANGE_ATTRIBUTES
    assert element.get("needsCompletedIntegratorStep") == "false"
    assert element.get("modelIdentifier") == root.find("CoSimulation").get("modelIdentifier") == name
    assert len(root.findall("ModelStructure/EventIndicator")) == len(FMUS[name].indicators)
