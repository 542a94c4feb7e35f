"""Each FMI 2.0 FMU is self-contained: it runs where dsc_fmu, numpy, fmpy and scipy cannot be imported.

``isolation.run_isolated`` runs the FMU through the ctypes driver ``fmi_ctypes.py`` in
``python -I -S`` with those packages blocked and recorded. No import of them may have been
attempted, only the standard library (not site-packages), the FMU's own files and the driver may
have been loaded, and the outputs must be finite and equal, to the last bit, to fmpy's in this
process for the same calls.
"""

import math
import sysconfig

import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from dsc_fmu.models import parameters as P
from isolation import REPO, bits, run_isolated, violations

RUNNER = r'''

def selftest():
    """The blocker must refuse the blocked packages even where they could be found on disk."""
    import importlib.machinery

    sys.path.extend(config.get("expose", []))
    results = {}
    for name in config["try_imports"]:
        top = name.partition(".")[0]
        findable = importlib.machinery.PathFinder.find_spec(top) is not None
        try:
            __import__(name)
            outcome = "imported"
        except ImportError as error:
            outcome = "ImportError: " + str(error)
        results[name] = {"findable_on_disk": findable, "outcome": outcome}
    return {"imports": results}


def run():
    unzipped = driver.extract(config["fmu"], config["workdir"])
    fmu = driver.Fmi2Slave(unzipped, config["instance"])
    fmu.instantiate(logging_on=True)
    fmu.setup_experiment(0.0)
    fmu.enter_initialization_mode()
    for name, value in config["real_parameters"].items():
        fmu.set_real([name], [value])
    for name, value in config["integer_parameters"].items():
        fmu.set_integer([name], [value])
    fmu.exit_initialization_mode()
    rows = []
    h = config["step_size"]
    for k, values in enumerate(config["schedule"]):
        if config["inputs"]:
            fmu.set_real(config["inputs"], values)
        rows.append(fmu.outputs())
        fmu.do_step(k * h, h)
    rows.append(fmu.outputs())
    fmu.terminate()
    alive = loaded_modules()
    fmu.free_instance()
    return {"rows": rows, "messages": fmu.messages, "unzipped": os.path.realpath(str(unzipped)), "modules": alive,
            "modules_after_free": sorted(loaded_modules()), "path_after_free": list(sys.path)}


report(selftest() if config["mode"] == "selftest" else run())
'''

CONTROLLER_M = [2.5, 1.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]
# Robot 1 m ahead of the reference: beta = 1 - k1 vr < beta_min, the guard acts and logs a warning.
CONTROLLER_GUARD = [3.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]

SCENARIOS = {
    "ReferenceRobot": dict(
        real_parameters={"eight_T": 20.0}, integer_parameters={"profile": 1}, inputs=[],
        schedule=[[] for _ in range(20)], step_size=0.05,
    ),
    "MobileRobot": dict(
        real_parameters={"max_step": 5e-4}, integer_parameters={}, inputs=["u1", "u2"],
        schedule=[[12.0 - 0.3 * k, 8.0 + 0.2 * k] for k in range(20)], step_size=0.01,
    ),
    "DSCController": dict(
        real_parameters={"k2": 2.5}, integer_parameters={}, inputs=[v.name for v in P.CONTROLLER_INPUTS],
        schedule=[[m + 0.002 * k * (i % 3 - 1) for i, m in enumerate(CONTROLLER_M if k < 14 else CONTROLLER_GUARD)]
                  for k in range(20)],
        step_size=1e-3,
    ),
}


def _outputs_by_type(md):
    kinds = {"Real": [], "Integer": [], "Boolean": []}
    for v in md.modelVariables:
        if v.causality == "output":
            kinds[v.type].append(v.name)
    return kinds


def _fmpy_run(md, unzipped, scenario):
    """The same calls as RUNNER's run(), through fmpy in this process."""
    kinds = _outputs_by_type(md)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(unzipped), modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="fmpy_reference")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    for name, value in scenario["real_parameters"].items():
        fmu.setReal([vr[name]], [value])
    for name, value in scenario["integer_parameters"].items():
        fmu.setInteger([vr[name]], [value])
    fmu.exitInitializationMode()

    def read():
        row = dict(zip(kinds["Real"], fmu.getReal([vr[n] for n in kinds["Real"]])))
        if kinds["Integer"]:
            row.update(zip(kinds["Integer"], fmu.getInteger([vr[n] for n in kinds["Integer"]])))
        if kinds["Boolean"]:
            row.update(zip(kinds["Boolean"], (bool(b) for b in fmu.getBoolean([vr[n] for n in kinds["Boolean"]]))))
        return row

    rows = []
    h = scenario["step_size"]
    for k, values in enumerate(scenario["schedule"]):
        if scenario["inputs"]:
            fmu.setReal([vr[n] for n in scenario["inputs"]], values)
        rows.append(read())
        fmu.doStep(k * h, h)
    rows.append(read())
    fmu.terminate()
    fmu.freeInstance()
    return rows


@pytest.mark.parametrize("name", ("ReferenceRobot", "MobileRobot", "DSCController"))
def test_fmu_runs_without_dsc_fmu_numpy_fmpy_scipy(fmu_paths, fmu_unzipped, tmp_path, name):
    md = read_model_description(str(fmu_paths[name]))
    scenario = SCENARIOS[name]
    config = dict(mode="run", fmu=str(fmu_paths[name]), workdir=str(tmp_path / "unzipped"),
                  instance=f"{name}_isolated", **scenario)
    result = run_isolated(RUNNER, config, tmp_path)

    # Isolated; our package with its own pythonfmu from inside the FMU, gone once the FMU is freed.
    assert violations(result, f"dsc_fmu_{name.lower()}_") == {}
    rows = result["rows"]
    assert len(rows) == len(scenario["schedule"]) + 1
    assert all(math.isfinite(v) for row in rows for v in row.values())
    assert [m for m in result["messages"] if m[1] > 1] == []  # nothing worse than a warning

    expected = _fmpy_run(md, fmu_unzipped[name], scenario)
    assert list(rows[0]) == list(expected[0])  # the driver finds fmpy's outputs, in fmpy's order
    assert bits(rows) == bits(expected)
    assert rows[0] != rows[-1]
    if name == "DSCController":
        # Integer and Boolean outputs and the (variadic) logger work through the ctypes driver too.
        assert rows[-1]["beta_guard_count"] > 0 and rows[-1]["beta_guard_active"] is True
        assert any(status == 1 and "beta" in message for _, status, _, message in result["messages"])


@pytest.mark.parametrize("module", ("numpy", "fmpy.fmi2", "scipy.linalg", "dsc_fmu", "dsc_fmu.models.plant"))
def test_blocker_refuses_and_records_what_would_otherwise_import(tmp_path, module):
    """Prove the mechanism: with site-packages and the repo back on sys.path the module is findable,
    yet the import fails and is recorded; a standard-library import still works."""
    site_packages = sysconfig.get_paths()["purelib"]
    config = dict(mode="selftest", try_imports=[module, "json"], expose=[site_packages, str(REPO)])
    result = run_isolated(RUNNER, config, tmp_path)
    outcome = result["imports"][module]
    assert outcome["findable_on_disk"] is True
    assert outcome["outcome"].startswith("ImportError") and "blocked" in outcome["outcome"]
    assert result["attempts"] and result["attempts"][0] == module.partition(".")[0]
    assert result["imports"]["json"]["outcome"] == "imported"
    assert result["blocked_loaded"] == []


def test_isolation_check_catches_an_fmu_that_imports_numpy(tmp_path, patched_mobile_robot):
    """A MobileRobot whose slave script tries ``import numpy`` (and copes without it) still runs,
    but the isolation run records the attempt, and only that: the check above fails for it."""
    leaky = patched_mobile_robot("from dsc_fmu.fmu.fmi2 import Fmi2ModelSlave",
                                 "\ntry:\n    import numpy\nexcept ImportError:\n    numpy = None\n", "leaky")

    config = dict(mode="run", fmu=str(leaky), workdir=str(tmp_path / "unzipped"), instance="leaky",
                  **SCENARIOS["MobileRobot"])
    result = run_isolated(RUNNER, config, tmp_path)
    found = violations(result, "dsc_fmu_mobilerobot_")
    assert list(found) == ["attempts"] and set(found["attempts"]) == {"numpy"}
    assert all(math.isfinite(v) for row in result["rows"] for v in row.values())
