"""Shared fixtures: the three FMUs, built once per test session into a temporary folder."""

import pytest

from dsc_fmu.build import build_fmus


@pytest.fixture(scope="session")
def fmu_paths(tmp_path_factory):
    """Paths of freshly built ReferenceRobot, MobileRobot and DSCController FMUs by name."""
    return build_fmus(tmp_path_factory.mktemp("fmus"))
