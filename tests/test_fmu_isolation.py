"""Each FMU is self-contained: it runs where dsc_fmu, numpy, fmpy and scipy cannot be imported.

A subprocess (``python -I -S``: no site-packages, no PYTHON* variables, no script or working folder
on sys.path, working folder a temporary one) first installs a ``sys.meta_path`` finder that refuses
and records every import of the blocked packages, drops the repository from ``sys.path``, then runs
the FMU through the ctypes driver ``fmi2_ctypes.py`` (standard library only). Its outputs must be
finite, equal to fmpy's in this process for the same calls, and the finder must have recorded no
attempt to import a blocked package.
"""

import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

import dsc_fmu.build as build_module
from dsc_fmu.build import FMUS, build_fmu
from dsc_fmu.models import parameters as P

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
DRIVER = TESTS / "fmi2_ctypes.py"
BLOCKED = ("numpy", "dsc_fmu", "fmpy", "scipy")

RUNNER = r'''
import sys

BLOCKED = ("numpy", "dsc_fmu", "fmpy", "scipy")
ATTEMPTS = []


class Blocker:
    """Refuse, and record, every import of a blocked top-level package."""

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            ATTEMPTS.append(name)
            raise ImportError(f"{name} is blocked: an FMU must not need it")
        return None


sys.meta_path.insert(0, Blocker())
PRELOADED = sorted(m for m in sys.modules if m.partition(".")[0] in BLOCKED)

import importlib.util
import json
import math
import os

config = json.loads(sys.argv[1])
repo = os.path.realpath(config["repo"])


def inside(path, folder):
    path = os.path.realpath(path)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


sys.path[:] = [p for p in sys.path if p and not inside(p, repo)]
PATH_AT_START = list(sys.path)

spec = importlib.util.spec_from_file_location("fmi2_ctypes", config["driver"])
driver = importlib.util.module_from_spec(spec)
spec.loader.exec_module(driver)


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

    def read():
        row = dict(zip(config["real_outputs"], fmu.get_real(config["real_outputs"])))
        if config["integer_outputs"]:
            row.update(zip(config["integer_outputs"], fmu.get_integer(config["integer_outputs"])))
        if config["boolean_outputs"]:
            row.update(zip(config["boolean_outputs"], fmu.get_boolean(config["boolean_outputs"])))
        return row

    rows = []
    h = config["step_size"]
    for k, values in enumerate(config["schedule"]):
        if config["inputs"]:
            fmu.set_real(config["inputs"], values)
        rows.append(read())
        fmu.do_step(k * h, h)
    rows.append(read())
    fmu.terminate()
    fmu.free_instance()
    modules = {}
    for name, module in list(sys.modules.items()):
        origin = getattr(module, "__file__", None)
        if origin:
            modules[name] = os.path.realpath(origin)
    return {
        "rows": rows,
        "messages": fmu.messages,
        "modules": modules,
        "unzipped": os.path.realpath(str(unzipped)),
    }


result = selftest() if config["mode"] == "selftest" else run()
result.update(
    attempts=ATTEMPTS,
    preloaded=PRELOADED,
    path_at_start=PATH_AT_START,
    flags={"isolated": sys.flags.isolated, "no_site": sys.flags.no_site},
    blocked_loaded=sorted(m for m in sys.modules if m.partition(".")[0] in BLOCKED),
)
print("RESULT " + json.dumps(result))
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


def _config(md, **kwargs):
    kinds = _outputs_by_type(md)
    return dict(
        repo=str(REPO), driver=str(DRIVER), real_outputs=kinds["Real"], integer_outputs=kinds["Integer"],
        boolean_outputs=kinds["Boolean"], **kwargs,
    )


def _isolated(config, cwd):
    """Run RUNNER in ``python -I -S`` from ``cwd`` with no PYTHON* variables; return its result."""
    script = Path(cwd) / "runner.py"
    script.write_text(RUNNER)
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    run = subprocess.run(
        [sys.executable, "-I", "-S", str(script), json.dumps(config)],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
    )
    lines = [line for line in run.stdout.splitlines() if line.startswith("RESULT ")]
    assert run.returncode == 0 and lines, f"exit {run.returncode}\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    return json.loads(lines[-1][len("RESULT "):])


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


def _allowed_roots(unzipped):
    paths = sysconfig.get_paths()
    return [os.path.realpath(p) for p in (paths["stdlib"], paths["platstdlib"], unzipped)] + [str(DRIVER)]


def _foreign_modules(result):
    """Modules the subprocess loaded from anywhere but the standard library, the FMU and the driver."""
    roots = _allowed_roots(result["unzipped"])

    def allowed(path):
        return any(path == root or path.startswith(root.rstrip(os.sep) + os.sep) for root in roots)

    return {name: path for name, path in result["modules"].items() if name != "__main__" and not allowed(path)}


@pytest.mark.parametrize("name", ("ReferenceRobot", "MobileRobot", "DSCController"))
def test_fmu_runs_without_dsc_fmu_numpy_fmpy_scipy(fmu_paths, fmu_unzipped, tmp_path, name):
    md = read_model_description(str(fmu_paths[name]))
    scenario = SCENARIOS[name]
    config = _config(md, mode="run", fmu=str(fmu_paths[name]), workdir=str(tmp_path / "unzipped"),
                     instance=f"{name}_isolated", **scenario)
    result = _isolated(config, tmp_path)

    assert result["flags"] == {"isolated": 1, "no_site": 1}
    assert result["preloaded"] == []
    assert not any(str(REPO) in p for p in result["path_at_start"])
    assert result["attempts"] == [], f"the FMU tried to import {result['attempts']}"
    assert result["blocked_loaded"] == []
    assert _foreign_modules(result) == {}
    # pythonfmu and our package come from inside the FMU.
    resources = os.path.join(result["unzipped"], "resources") + os.sep
    assert result["modules"]["pythonfmu"].startswith(resources)
    bundled = [n for n in result["modules"] if n.startswith(f"dsc_fmu_{name.lower()}_")]
    assert bundled and all(result["modules"][n].startswith(resources) for n in bundled)

    rows = result["rows"]
    assert len(rows) == len(scenario["schedule"]) + 1
    assert all(math.isfinite(v) for row in rows for v in row.values())
    assert [m for m in result["messages"] if m[1] > 1] == []  # nothing worse than a warning

    expected = _fmpy_run(md, fmu_unzipped[name], scenario)
    assert rows == expected
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
    config = dict(repo=str(REPO), driver=str(DRIVER), mode="selftest", try_imports=[module, "json"],
                  expose=[site_packages, str(REPO)])
    result = _isolated(config, tmp_path)
    outcome = result["imports"][module]
    assert outcome["findable_on_disk"] is True
    assert outcome["outcome"].startswith("ImportError") and "blocked" in outcome["outcome"]
    assert result["attempts"] and result["attempts"][0] == module.partition(".")[0]
    assert result["imports"]["json"]["outcome"] == "imported"
    assert result["blocked_loaded"] == []


def test_isolation_check_catches_an_fmu_that_imports_numpy(tmp_path, monkeypatch, fmu_paths):
    """A MobileRobot whose slave script tries ``import numpy`` (and copes without it) still runs,
    but the isolation run records the attempt: the check above would fail for it."""
    sources = tmp_path / "fmu_sources"
    shutil.copytree(build_module._sources_dir(), sources)
    script = sources / FMUS["MobileRobot"].script
    text = script.read_text()
    marker = "from dsc_fmu.fmi_slave import DscSlave"
    assert marker in text, "the test's source patch no longer applies to mobile_robot.py"
    script.write_text(text.replace(marker, marker + "\ntry:\n    import numpy\nexcept ImportError:\n    numpy = None\n", 1))
    monkeypatch.setattr(build_module, "_sources_dir", lambda: sources)
    leaky = build_fmu(FMUS["MobileRobot"], tmp_path / "leaky")
    monkeypatch.undo()

    md = read_model_description(str(leaky))
    config = _config(md, mode="run", fmu=str(leaky), workdir=str(tmp_path / "unzipped"),
                     instance="leaky", **SCENARIOS["MobileRobot"])
    result = _isolated(config, tmp_path)
    assert result["attempts"] and set(result["attempts"]) == {"numpy"}
    assert result["blocked_loaded"] == []
    assert all(math.isfinite(v) for row in result["rows"] for v in row.values())
