"""The newest CPythons for real: Debian unstable's CPython 3.14 and 3.15 (builds that need a newer glibc than
this machine's) in an mmdebstrap root of the unstable suite (``debian_root.py``), against the same runs here
with the CPython that built the FMUs: each FMU (FMI 2.0 and 3.0) in the project's C importer started in the
root from an empty environment with DSC_FMU_PYTHON naming the root's CPython, and our master on fmpy running
on each of the root's CPythons, which the FMUs adopt. Which CPython served is checked, not assumed: from the
dynamic loader's trace (LD_DEBUG) in the C importer, from an audit hook in fmpy's process."""

import json
import re
import shutil
import tempfile
import zipfile
from pathlib import Path

import pytest
from fmpy import extract, read_model_description

from c_hosts import EMPTY_ENVIRONMENT, HERE, compile_c, parse_rows, run_c
from debian_root import (PAPER_STOP, Site, Specification, assert_identical, cached_root, copied, fmu_outputs,
                         host_versions, paper_cosimulation, served_paper_cosimulation)
from test_c_importer import STEP as STEP_API, STEPS as STEPS_API, c_run
from test_cpython_api import ADOPT, NEVER, OLDER_ONLY, absent_build, controller
from dsc_fmu.fmubuild.binary import ENTRY_FILE, LINUX, OVERRIDE_VARIABLE, build_python
from dsc_fmu.scenario import load_scenario

pytestmark = pytest.mark.slow

PYTHONS = ("3.14", "3.15")
# What dsc_fmu.cosimulate on fmpy imports; numpy and lxml of the host's version may have no wheel for the
# newest CPython (numpy 2.4 has none for 3.15): that version or a newer one.
PYTHON_PACKAGES = ("numpy", "fmpy", "attrs", "lxml")
LIBRARIES = "/usr/lib/x86_64-linux-gnu"
NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
STEP = 0.02
STEPS = round(PAPER_STOP / STEP)
# DSC_FMU_PYTHON as users write it, and the CPython it must start: a library, or an installation's folder
# (where the newest serves, the building 3.11 being absent).
SERVED = {"3.14-library": ("3.14", f"{LIBRARIES}/libpython3.14.so.1.0"),
          "3.15-library": ("3.15", f"{LIBRARIES}/libpython3.15.so.1.0"),
          "3.15-folder": ("3.15", "/usr")}
# LD_DEBUG=files: "file=<path> [0];  dynamically loaded by <path> [0]" for each dlopen.
LOADED = re.compile(r"file=(?P<file>\S+) \[\d+\];\s+dynamically loaded by (?P<by>\S+) \[")


def specification() -> Specification:
    """Debian unstable's CPython 3.14 and 3.15 (interpreters and shared libraries), each with its site, and the
    C++ runtime NumPy's wheels need."""
    packages = (*(f"{kind}{python}" for python in PYTHONS for kind in ("python", "libpython")), "libstdc++6")
    return Specification("sid", "sid", packages,
                         tuple(Site(python, ("manylinux_2_28_x86_64", "manylinux2014_x86_64"),
                                    host_versions(PYTHON_PACKAGES, at_least=("numpy", "lxml"))) for python in PYTHONS))


@pytest.fixture(scope="module")
def sid_root():
    return cached_root(specification())


@pytest.fixture()
def workspace(sid_root):
    """A folder in the root with the project's sources, removed after the test."""
    folder = sid_root.workspace()
    yield folder
    shutil.rmtree(folder)


@pytest.fixture(scope="module")
def importer(sid_root):
    """``c_importer`` compiled here, in a folder of the root's: both sides run this file."""
    (sid_root.path / "work").mkdir(exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix="c-", dir=sid_root.path / "work"))
    yield compile_c("c_importer.c", folder / "c_importer")
    shutil.rmtree(folder)


def loaded(stderr: str) -> dict:
    """What the dynamic loader's trace says was loaded with dlopen: each file and what loaded it."""
    return {match["file"]: match["by"] for match in LOADED.finditer(stderr)}


def entry(path: Path) -> tuple[str, str]:
    """The FMU's bridge module and slave module, as its binary's entry file names them."""
    with zipfile.ZipFile(path) as fmu:
        bridge, slave = fmu.read(f"resources/{ENTRY_FILE}").decode().split()[:2]
    return bridge, slave


@pytest.mark.parametrize("served", SERVED)
@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_each_fmu_in_the_c_importer_on_the_newest_cpythons_equals_the_building_cpython(
        sid_root, importer, workspace, fmu_paths, fmu3_paths, tmp_path, name, version, served):
    """The same file in the same C importer, here with the building CPython and in the root with DSC_FMU_PYTHON
    naming 3.14 or 3.15: the same rows to the bit; the root's process loaded that CPython's library (from the
    FMU's binary) and its standard library's extension modules, and no other CPython."""
    python, named = SERVED[served]
    path = (fmu_paths if version == 2 else fmu3_paths)[name]
    md = read_model_description(str(path))
    token = md.guid if version == 2 else md.instantiationToken
    refs = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Float64")]
    folder = Path(extract(str(path), unzipdir=workspace / name))
    command = lambda importer, folder: [importer, version, folder, name, token, STEPS, STEP, *refs]  # noqa: E731
    host = run_c(command(importer, folder), tmp_path, {**EMPTY_ENVIRONMENT, "LD_DEBUG": "files"})
    inside = sid_root.run(command(sid_root.inside(importer), sid_root.inside(folder)),
                          env={OVERRIDE_VARIABLE: named, "LD_DEBUG": "files"})
    assert host.returncode == 0, host.stderr[-3000:]
    assert inside.returncode == 0, inside.stderr[-3000:]
    building = [file for file in loaded(host.stderr) if "/libpython" in file]
    assert [Path(file).name for file in building] == [f"libpython{build_python().version}.so.1.0"], building
    binary = f"{sid_root.inside(folder)}/{LINUX.file(version, name)}"
    libraries = {file: by for file, by in loaded(inside.stderr).items() if "/libpython" in file}
    assert libraries == {f"{LIBRARIES}/libpython{python}.so.1.0": binary}, libraries
    extensions = {str(Path(file).parent) for file in loaded(inside.stderr) if "/lib-dynload/" in file}
    assert extensions == {f"/usr/lib/python{python}/lib-dynload"}, extensions
    assert len(parse_rows(inside.stdout)) == STEPS + 1 and len(refs) > 2
    assert inside.stdout == host.stdout


@pytest.mark.parametrize("python", PYTHONS)
@pytest.mark.parametrize("version", (2, 3))
def test_the_paper_scenario_through_our_master_on_fmpy_on_the_newest_cpythons_equals_the_building_cpython(
        sid_root, workspace, fmu_paths, fmu3_paths, version, python):
    """Our master over the paper's first 2 s on fmpy running on the root's CPython 3.14 or 3.15 (the FMUs
    adopt the CPython of the process): that CPython executed every FMU's bridge and slave code, and the
    result equals the same run here to the bit, the columns the master computes with NumPy too (the root's
    NumPy may be newer than the host's)."""
    fmus = copied(fmu_paths if version == 2 else fmu3_paths, workspace / "fmus")
    inside = sid_root.run_task(workspace, served_paper_cosimulation, fmus, python=python)
    host = paper_cosimulation(fmus)
    assert inside["version"][:2] == [3, int(python.split(".")[1])]
    assert inside["executable"] == f"/usr/bin/python{python}"
    for path in fmus.values():
        bridge, slave = entry(path)
        assert {f"{bridge.replace('.', '/')}.py", f"{slave}.py"} <= set(inside["executed"]), inside["executed"]
    assert inside["steps"] == host["steps"] == round(PAPER_STOP / load_scenario("paper").simulation.step_size)
    inside, host = inside["result"], host["result"]
    assert inside.dtype == host.dtype and len(inside) == len(host) and host["time"][-1] == PAPER_STOP
    outputs = fmu_outputs(fmus)
    assert len(outputs & set(host.dtype.names)) > 30 and "position_error" not in outputs
    assert_identical(inside, host, host.dtype.names)


@pytest.mark.parametrize("python", PYTHONS)
def test_without_every_removed_and_deprecated_name_the_newest_cpythons_start_and_are_adopted(
        sid_root, importer, workspace, fmu_paths, tmp_path, python):
    """The build that treats every removed, deprecated and private name as absent (``test_cpython_api.py``):
    started by the C importer through PEP 741, and adopted inside the root's ``python3.X`` (ctypes), both with
    the rows of the default build here."""
    md, outputs = controller(fmu_paths, tmp_path / "default")
    expected = parse_rows(c_run(importer, 2, tmp_path / "default", md, outputs, tmp_path).stdout)
    folder = workspace / "absent"
    controller(fmu_paths, folder, absent_build((*NEVER, *OLDER_ONLY)))
    started = sid_root.run([sid_root.inside(importer), 2, sid_root.inside(folder), "DSCController", md.guid, STEPS_API,
                            STEP_API, *outputs], env={OVERRIDE_VARIABLE: f"{LIBRARIES}/libpython{python}.so.1.0"})
    assert started.returncode == 0, started.stderr[-3000:]
    assert parse_rows(started.stdout) == expected
    shutil.copy(HERE / "fmi_ctypes.py", workspace / "fmi_ctypes.py")
    by_reference = {v.valueReference: v.name for v in md.modelVariables}
    names = ",".join(by_reference[int(reference)] for reference in outputs)
    adopted = sid_root.run([f"/usr/bin/python{python}", "-I", "-c", ADOPT, sid_root.inside(workspace / "fmi_ctypes.py"),
                            sid_root.inside(folder), names, STEPS_API, repr(STEP_API)])
    assert adopted.returncode == 0, adopted.stderr[-3000:]
    report = json.loads(adopted.stdout.splitlines()[-1])
    assert report["version"].startswith(python + ".") and report["rows"] == expected


def test_an_fmu_under_a_non_ascii_path_runs_on_the_newest_cpython_from_the_c_locale(sid_root, importer, workspace,
                                                                                    fmu_paths, tmp_path):
    """UTF-8 mode through PEP 741: DSCController under "Röbot 模型" in the root, CPython 3.15 started from an
    empty environment, gives the rows of the default build here."""
    md, outputs = controller(fmu_paths, tmp_path / "default")
    expected = parse_rows(c_run(importer, 2, tmp_path / "default", md, outputs, tmp_path).stdout)
    folder = workspace / "Röbot 模型"
    controller(fmu_paths, folder)
    run = sid_root.run([sid_root.inside(importer), 2, sid_root.inside(folder), "DSCController", md.guid, STEPS_API,
                        STEP_API, *outputs], env={OVERRIDE_VARIABLE: f"{LIBRARIES}/libpython3.15.so.1.0"})
    assert run.returncode == 0, run.stderr[-3000:]
    assert parse_rows(run.stdout) == expected
