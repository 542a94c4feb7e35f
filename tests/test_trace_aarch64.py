"""The traced C on aarch64 Linux (under qemu-user in the arm64 Debian root of ``aarch64.py``): cross-compiled
here with ``-ffp-contract=off``, equal bit for bit to the root's CPython on the points of ``traced_cases``
(without the flag aarch64 fuses multiply-adds and the tangents differ: docs/traced-c.md)."""

import shutil
from pathlib import Path

import pytest

from aarch64 import cached_arm64_root
from dsc_fmu.fmubuild.binary import LINUX_AARCH64
from dsc_fmu.fmubuild.emit_c import C_FLAGS
from dsc_fmu.fmubuild.traced_models import compile_library, trace_models
from traced_cases import traced_points

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def arm64_root():
    return cached_arm64_root()


@pytest.fixture()
def workspace(arm64_root):
    """A folder in the root with the project's sources and ``traced_cases.py``, removed after the test."""
    root = arm64_root
    folder = root.workspace(Path(__file__).parent / "traced_cases.py")
    yield root, folder
    shutil.rmtree(folder)


def test_the_traced_c_on_aarch64_equals_its_cpython(workspace):
    root, folder = workspace
    build = folder / "build"
    build.mkdir()
    library = compile_library(trace_models().source, build, LINUX_AARCH64, C_FLAGS)
    found = root.run_task(folder, traced_points, {"traced": library})
    assert found["differing"] == {}
    assert found["counts"]["controller held=False adaptation=0"]["series"] >= 700, found["counts"]
