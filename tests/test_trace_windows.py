"""The traced C on Windows: cross-compiled here as a DLL whose C-library math is the Universal C Runtime's, as
CPython's is, and under Wine equal bit for bit to the official embeddable CPython 3.11 on the points of
``traced_cases`` (docs/traced-c.md). Wine's UCRT is Wine's own: real Windows is not checked here."""

import json
from pathlib import Path

import pefile
import pytest

from dsc_fmu.fmubuild.binary import WINDOWS
from dsc_fmu.fmubuild.traced_models import compile_library, trace_models
from wine import embeddable_python, windows_path

pytestmark = pytest.mark.slow

ROOT = Path(__file__).parents[1]
SCRIPT = """import json, sys
sys.path[:0] = [{tests!r}, {source!r}]
import traced_cases
print(json.dumps(traced_cases.traced_points({{"traced": {library!r}}})))
"""


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return compile_library(trace_models().source, tmp_path_factory.mktemp("traced"), WINDOWS)


def test_the_dll_takes_its_math_from_the_ucrt(library):
    """MinGW-w64 would link its own ``sin``, ``cos`` and ``fmod`` into the DLL; ``traced_math.h`` imports them."""
    dll = pefile.PE(str(library))
    imported = {entry.dll.decode(): {symbol.name.decode() for symbol in entry.imports}
                for entry in dll.DIRECTORY_ENTRY_IMPORT}
    assert {"sin", "cos", "atan", "fmod"} <= imported["api-ms-win-crt-math-l1-1-0.dll"], imported


def test_the_traced_c_on_windows_equals_its_cpython(wine, library, tmp_path):
    python = embeddable_python(11, tmp_path / "python")
    script = tmp_path / "run.py"
    script.write_text(SCRIPT.format(tests=windows_path(ROOT / "tests"), source=windows_path(ROOT),
                                    library=windows_path(library)))
    run = wine.run([python / "python.exe", windows_path(script)], timeout=1200)
    assert run.returncode == 0, run.stderr[-3000:]
    found = json.loads(run.stdout.strip().splitlines()[-1])
    assert found["differing"] == {}
    assert found["counts"]["controller held=False adaptation=0"]["series"] >= 700, found["counts"]
