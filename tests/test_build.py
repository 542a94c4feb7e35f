"""The builder: FMUs rebuilt only when missing or built from other sources; unique bundled names."""

import json
import os
import stat
import subprocess
import sys
import zipfile

import pytest

from dsc_fmu.fmubuild import fmus as build
from dsc_fmu.fmubuild.binary import BinaryBuildError
from dsc_fmu.fmubuild.fmus import ensure_fmus, source_hash
from dsc_fmu.identity import BUILD_ID_FILE, fmu_build_id
from dsc_fmu.registry import FMUS


def test_ensure_builds_missing_fmus_then_reuses_them(tmp_path):
    first = ensure_fmus(tmp_path)
    assert set(first) == set(FMUS)
    stamps = {name: path.stat().st_mtime_ns for name, path in first.items()}
    second = ensure_fmus(tmp_path)
    assert {name: path.stat().st_mtime_ns for name, path in second.items()} == stamps
    for name, path in first.items():
        assert fmu_build_id(path) == source_hash(FMUS[name])


def test_ensure_rebuilds_an_fmu_built_from_other_sources(tmp_path):
    paths = ensure_fmus(tmp_path)
    stale = paths["MobileRobot"]
    with zipfile.ZipFile(stale) as archive:
        entries = {item: archive.read(item) for item in archive.namelist()}
    entries[BUILD_ID_FILE] = json.dumps({"source_hash": "from an older checkout"}).encode()
    with zipfile.ZipFile(stale, "w") as archive:
        for item, data in entries.items():
            archive.writestr(item, data)
    assert fmu_build_id(stale) == "from an older checkout"
    ensure_fmus(tmp_path)
    assert fmu_build_id(stale) == source_hash(FMUS["MobileRobot"])


def test_fmus_built_by_another_machine_s_cpython_are_used_as_they_are(tmp_path, monkeypatch):
    """The Python a binary prefers is not a source: FMUs built where another CPython (another version,
    library and home) built them are current here, their binaries keep that preference, nothing is rebuilt."""
    import dsc_fmu.fmubuild.binary as binary

    elsewhere = binary.PythonRuntime("3.13", "/opt/elsewhere/lib/libpython3.13.so.1.0", "/opt/elsewhere")
    with monkeypatch.context() as patch:
        patch.setattr(binary, "build_python", lambda: elsewhere)
        first = build.build_fmus(tmp_path)
    stamps = {name: path.stat().st_mtime_ns for name, path in first.items()}
    again = ensure_fmus(tmp_path)
    assert {name: path.stat().st_mtime_ns for name, path in again.items()} == stamps
    with zipfile.ZipFile(again["MobileRobot"]) as fmu:
        assert elsewhere.library.encode() in fmu.read(binary.LINUX.file(2, "MobileRobot"))


def test_ensure_replaces_a_file_that_is_not_an_fmu(tmp_path):
    (tmp_path / "DSCController.fmu").write_text("not a zip")
    path = ensure_fmus(tmp_path)["DSCController"]
    assert zipfile.is_zipfile(path)


def test_source_hash_follows_the_sources(monkeypatch, tmp_path):
    spec = FMUS["ReferenceRobot"]
    before = source_hash(spec)
    fake = tmp_path / "fmu_sources"
    fake.mkdir()
    for script in (build._sources_dir()).glob("*.py"):
        (fake / script.name).write_text(script.read_text())
    monkeypatch.setattr(build, "_sources_dir", lambda: fake)
    assert source_hash(spec) == before
    (fake / spec.script).write_text((fake / spec.script).read_text() + "\n# changed\n")
    assert source_hash(spec) != before


@pytest.mark.parametrize("name", list(FMUS))
def test_bundled_modules_carry_a_name_unique_to_the_build(fmu_paths, name):
    with zipfile.ZipFile(fmu_paths[name]) as archive:
        module = archive.read("resources/slavemodule.txt").decode()
        files = archive.namelist()
    digest = source_hash(FMUS[name])[:12]
    assert module.endswith(digest)
    package = f"resources/dsc_fmu_{name.lower()}_{digest}/"
    assert f"{package}models/controller.py" in files
    assert not any(f.startswith("resources/dsc_fmu/") for f in files)
    with zipfile.ZipFile(fmu_paths[name]) as archive:
        script = archive.read(f"resources/{module}.py").decode()
    assert "from dsc_fmu." not in script


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_fmus_are_written_with_the_users_usual_permissions(tmp_path, umask):
    """An FMU is readable as any file the user writes: 0o666 less the umask (not mkstemp's 0600)."""
    old = os.umask(umask)
    try:
        path = build.build_fmu(FMUS["ReferenceRobot"], tmp_path)
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
    assert [p.name for p in tmp_path.iterdir()] == ["ReferenceRobot.fmu"]  # no partial file left


def test_a_public_import_of_the_fmi_library_fails_the_build(patched_mobile_robot):
    """Every bundled import of pythonfmu must be one the build can make private; any other form would
    load whatever pythonfmu the importing process has."""
    with pytest.raises(BinaryBuildError, match=r"imports pythonfmu by its public name \(import pythonfmu\)"):
        patched_mobile_robot("from dsc_fmu.fmu.fmi2 import Fmi2ModelSlave", "\nimport pythonfmu\n", "public")


def test_an_fmu_loaded_in_this_process_does_not_hide_its_sources_from_the_next_build(tmp_path):
    """A build imports the slave script under the name the FMU's resources give it; an instance of an
    FMU of the same build in the process has imported that name from its resources first."""
    script = """
import sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from dsc_fmu.fmubuild.fmus import build_fmu, source_hash
from dsc_fmu.identity import fmu_build_id
from dsc_fmu.registry import FMUS
spec = FMUS["ReferenceRobot"]
first = build_fmu(spec, sys.argv[1] + "/first")
unzipped = extract(str(first), unzipdir=sys.argv[1] + "/unzipped")
description = read_model_description(unzipped)
instance = FMU2Slave(guid=description.guid, unzipDirectory=unzipped, instanceName="r",
                     modelIdentifier=description.coSimulation.modelIdentifier)
instance.instantiate()
instance.setupExperiment(startTime=0.0)
instance.enterInitializationMode()
instance.exitInitializationMode()
again = build_fmu(spec, sys.argv[1] + "/again")
instance.doStep(0.0, 1e-3)
instance.terminate()
instance.freeInstance()
print(fmu_build_id(again) == source_hash(spec))
"""
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "True"
