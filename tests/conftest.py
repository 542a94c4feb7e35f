"""Shared fixtures: the three FMUs, built once per test session into a temporary folder."""

import pytest

from dsc_fmu.build import build_fmus


@pytest.fixture(scope="session")
def fmu_paths(tmp_path_factory):
    """Paths of freshly built ReferenceRobot, MobileRobot and DSCController FMUs by name."""
    return build_fmus(tmp_path_factory.mktemp("fmus"))


@pytest.fixture(scope="session")
def fmu_unzipped(fmu_paths, tmp_path_factory):
    """The three FMUs of ``fmu_paths`` extracted once per session (with fmpy), by name."""
    from fmpy import extract

    root = tmp_path_factory.mktemp("unzipped")
    return {name: extract(path, unzipdir=root / name) for name, path in fmu_paths.items()}
