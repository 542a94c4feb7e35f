"""Shared fixtures: the three FMUs (FMI 2.0 and 3.0), built once per test session into temporary folders;
a Wine prefix per module."""

import shutil

import pytest

import dsc_fmu.fmubuild.fmus as build_module
from dsc_fmu.fmubuild.fmus import build_fmu, build_fmus
from dsc_fmu.registry import FMUS


@pytest.fixture(scope="session")
def fmu_paths(tmp_path_factory):
    """Paths of freshly built ReferenceRobot, MobileRobot and DSCController FMUs by name."""
    return build_fmus(tmp_path_factory.mktemp("fmus"))


@pytest.fixture(scope="session")
def fmu3_paths(tmp_path_factory):
    """The same three FMUs as FMI 3.0 co-simulation FMUs (pythonfmu3), by name."""
    return build_fmus(tmp_path_factory.mktemp("fmus3"), fmi_version=3)


@pytest.fixture(scope="session")
def untraced_fmu_paths(tmp_path_factory):
    """The three FMI 2.0 FMUs built without the C traced from their models (``--no-traced``): Python only."""
    return build_fmus(tmp_path_factory.mktemp("fmus_untraced"), traced=False)


@pytest.fixture(scope="session")
def fmu_unzipped(fmu_paths, tmp_path_factory):
    """The three FMUs of ``fmu_paths`` extracted once per session (with fmpy), by name."""
    from fmpy import extract

    root = tmp_path_factory.mktemp("unzipped")
    return {name: extract(path, unzipdir=root / name) for name, path in fmu_paths.items()}


@pytest.fixture(scope="module")
def wine(tmp_path_factory):
    """A Wine prefix of the module's own, booted (``wine.start_wine``)."""
    from wine import start_wine

    return start_wine(tmp_path_factory.mktemp("wine") / "prefix")


@pytest.fixture()
def patched_mobile_robot(tmp_path, monkeypatch):
    """Build a MobileRobot FMU from a copy of ``fmu_sources`` whose slave script has ``addition``
    inserted after ``marker``: ``build(marker, addition, folder_name)`` returns its path. Built without the traced
    C (``--no-traced``), which is traced from the models and would not follow the patched slave."""

    def build(marker: str, addition: str, folder_name: str):
        sources = tmp_path / f"fmu_sources_{folder_name}"
        shutil.copytree(build_module._sources_dir(), sources)
        script = sources / FMUS["MobileRobot"].script
        text = script.read_text()
        assert marker in text, "the test's source patch no longer applies to mobile_robot.py"
        script.write_text(text.replace(marker, marker + addition, 1))
        with monkeypatch.context() as patch:
            patch.setattr(build_module, "_sources_dir", lambda: sources)
            return build_fmu(FMUS["MobileRobot"], tmp_path / folder_name, traced=False)

    return build
