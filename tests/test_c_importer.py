"""The FMUs in a non-Python importer: a C program that loads them as OMSimulator or libcosim would.

pythonfmu 0.7.0's Linux binary leaves the Python C API undefined (it expects a process that has
libpython loaded): a C importer needs LD_PRELOAD of libpython (and PYTHONHOME), as the README says.
"""

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

SOURCE = Path(__file__).with_name("c_importer.c")
LIBPYTHON = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("LDLIBRARY") or "")
STEPS, STEP = 50, 0.02

pytestmark = pytest.mark.skipif(
    shutil.which("gcc") is None or not sysconfig.get_config_var("Py_ENABLE_SHARED") or not LIBPYTHON.is_file(),
    reason="needs gcc and a shared libpython",
)


@pytest.fixture(scope="module")
def importer(tmp_path_factory):
    binary = tmp_path_factory.mktemp("c") / "c_importer"
    subprocess.run(["gcc", "-O1", "-o", str(binary), str(SOURCE), "-ldl"], check=True)
    return binary


def unzipped(fmu: Path, folder: Path) -> Path:
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(folder)
    return folder


def c_run(importer, folder, md, refs, preload=True):
    env = {key: value for key, value in os.environ.items() if not key.startswith("PYTHON")}
    if preload:
        env.update(LD_PRELOAD=str(LIBPYTHON), PYTHONHOME=sys.base_prefix)
    return subprocess.run(
        [str(importer), str(folder), md.coSimulation.modelIdentifier, md.guid, str(STEPS), str(STEP), *map(str, refs)],
        capture_output=True, text=True, env=env, timeout=120,
    )


def fmpy_run(folder, md, refs):
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(folder), modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="fmpy")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    rows = []
    for k in range(STEPS + 1):
        rows.append([k * STEP, *fmu.getReal(refs)])
        if k < STEPS:
            fmu.doStep(k * STEP, STEP)
    fmu.terminate()
    fmu.freeInstance()
    return rows


@pytest.mark.parametrize("name", ["ReferenceRobot", "MobileRobot", "DSCController"])
def test_a_c_importer_runs_each_fmu_like_fmpy(importer, fmu_paths, tmp_path, name):
    md = read_model_description(str(fmu_paths[name]))
    refs = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    folder = unzipped(fmu_paths[name], tmp_path / name)
    run = c_run(importer, folder, md, refs)
    assert run.returncode == 0, run.stderr
    rows = [[float(value) for value in line.split(",")] for line in run.stdout.splitlines()]
    assert rows == fmpy_run(folder, md, refs)
    assert len(rows) == STEPS + 1


def test_without_libpython_the_c_importer_cannot_load_the_binary(importer, fmu_paths, tmp_path):
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    run = c_run(importer, unzipped(fmu_paths["ReferenceRobot"], tmp_path / "r"), md, [0], preload=False)
    assert run.returncode == 1
    assert "undefined symbol: _Py" in run.stderr
