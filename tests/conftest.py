"""Shared fixtures: the three FMUs (FMI 2.0 and 3.0), built once per test session into temporary folders."""

import pytest

from dsc_fmu.build import build_fmus


@pytest.fixture(scope="session")
def fmu_paths(tmp_path_factory):
    """Paths of freshly built ReferenceRobot, MobileRobot and DSCController FMUs by name."""
    return build_fmus(tmp_path_factory.mktemp("fmus"))


@pytest.fixture(scope="session")
def fmu3_paths(tmp_path_factory):
    """The same three FMUs as FMI 3.0 co-simulation FMUs (pythonfmu3), by name."""
    return build_fmus(tmp_path_factory.mktemp("fmus3"), fmi_version=3)


@pytest.fixture(scope="session")
def fmu_unzipped(fmu_paths, tmp_path_factory):
    """The three FMUs of ``fmu_paths`` extracted once per session (with fmpy), by name."""
    from fmpy import extract

    root = tmp_path_factory.mktemp("unzipped")
    return {name: extract(path, unzipdir=root / name) for name, path in fmu_paths.items()}
