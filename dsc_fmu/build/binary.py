"""The FMUs' binary layer: ``dsc_fmu/build/native`` compiled with Zig's C compiler (the ``ziglang`` package).

The binary replaces pythonfmu's and pythonfmu3's Linux binaries in every FMU. It links no
Python: it finds one at run time (``native/pyhost.c``), so the FMUs load in C and C++ importers
with no set-up. Zig comes from the package index with everything it needs (a C compiler, a
linker and the glibc stubs), so building needs no system compiler; it targets glibc 2.17, so
the binary also loads on Linux distributions older than the one that built it.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..errors import DscFmuError
from ..fmu.native_bridge import CAUSALITIES, TYPES, VARIABILITIES

__all__ = [
    "BinaryBuildError", "PythonRuntime", "build_python", "compile_binary", "binary_sources", "binary_folder",
    "OVERRIDE_VARIABLE", "ENTRY_FILE",
]

NATIVE_DIR = Path(__file__).parent / "native"
OVERRIDE_VARIABLE = "DSC_FMU_PYTHON"
# The file in an FMU's resources that names what the binary imports and creates:
# "<bridge module> <slave module> <slave class> <GUID or token>"; the bridge's top level is the
# build's private package.
ENTRY_FILE = "dsc_fmu_entry.txt"
GLIBC = "2.17"
# FMI platform folders of the binary this module builds (x86_64 Linux).
FOLDERS = {2: "linux64", 3: "x86_64-linux"}
_SOURCES = {2: ("fmi2Functions.c", "instance.c", "slave.c", "pyhost.c"), 3: ("fmi3Functions.c", "instance.c", "slave.c", "pyhost.c")}


class BinaryBuildError(DscFmuError, RuntimeError):
    """The FMU binary could not be compiled (the message names the command and the compiler's output)."""


@dataclass(frozen=True)
class PythonRuntime:
    """The Python the binary looks for: its minor version, the shared library (or "") and home of the
    Python that built it, and the file name of the system's shared library of that version."""

    version: str
    library: str
    home: str
    soname: str = ""

    @property
    def system_library(self) -> str:
        return self.soname or f"libpython{self.version}.so.1.0"


def build_python() -> PythonRuntime:
    """The running Python: the one that builds the FMUs and that they look for first after the override."""
    library = ""
    if sysconfig.get_config_var("Py_ENABLE_SHARED"):
        candidate = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("INSTSONAME") or "")
        if candidate.is_file():
            library = str(candidate.resolve())
    return PythonRuntime(f"{sys.version_info.major}.{sys.version_info.minor}", library, sys.base_prefix)


def binary_folder(fmi_version: int) -> str | None:
    """The FMI platform folder this machine's binary goes to, or None where it is not built (not x86_64 Linux)."""
    if sys.platform != "linux" or platform.machine() != "x86_64":
        return None
    return FOLDERS[fmi_version]


def binary_sources(fmi_version: int) -> list[Path]:
    """Every file the binary of ``fmi_version`` is compiled from."""
    return [NATIVE_DIR / name for name in (*_SOURCES[fmi_version], "instance.h", "pyhost.h", "slave.h")]


def _fmi_headers() -> Path:
    """The FMI standard's headers, as FMPy ships them."""
    import fmpy

    return Path(fmpy.__file__).parent / "c-code"


def _c_string(text: str) -> str:
    return json.dumps(text)


def _contract() -> list[str]:
    """The codes of ``fmu/native_bridge.py``, their owner, as the defines ``slave.h`` takes them."""
    tables = {"TYPE": TYPES, "CAUSALITY": CAUSALITIES, "VARIABILITY": VARIABILITIES}
    named = {(kind, code): name for kind, table in tables.items() for name, code in reversed(table.items())}
    return [f"-DDSC_{kind}_{name.upper()}={code}" for (kind, code), name in named.items()]


def _command(fmi_version: int, runtime: PythonRuntime, output: Path) -> list[str]:
    return [
        sys.executable, "-m", "ziglang", "cc", "-target", f"x86_64-linux-gnu.{GLIBC}", "-shared", "-fPIC", "-O2",
        "-std=c11", "-fvisibility=hidden", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
        f"-I{NATIVE_DIR}", f"-I{_fmi_headers()}",
        f"-DDSC_PYTHON_VERSION={_c_string(runtime.version)}",
        f"-DDSC_BUILD_LIBPYTHON={_c_string(runtime.library)}",
        f"-DDSC_BUILD_PYTHON_HOME={_c_string(runtime.home)}",
        f"-DDSC_PYTHON_SONAME={_c_string(runtime.system_library)}",
        f"-DDSC_ENTRY_FILE={_c_string(ENTRY_FILE)}",
        *_contract(),
        *(str(NATIVE_DIR / name) for name in _SOURCES[fmi_version]),
        "-o", str(output), "-ldl", "-lpthread", "-lm",
    ]


def _compiler_environment() -> dict:
    """The environment for Zig: it keeps its cache under HOME or XDG_CACHE_HOME; without either, in the temp folder."""
    env = dict(os.environ)
    if not any(env.get(key) for key in ("ZIG_GLOBAL_CACHE_DIR", "XDG_CACHE_HOME", "HOME")):
        env["ZIG_GLOBAL_CACHE_DIR"] = str(Path(tempfile.gettempdir()) / "dsc-fmu-zig-cache")
    return env


def compile_binary(fmi_version: int, runtime: PythonRuntime | None = None) -> bytes:
    """The shared library of the FMI ``fmi_version`` layer for ``runtime`` (default: ``build_python()``)."""
    runtime = runtime or build_python()
    digest = hashlib.sha256(repr((fmi_version, runtime, _contract())).encode())
    for path in binary_sources(fmi_version):
        digest.update(path.read_bytes())
    return _compile(fmi_version, runtime, digest.hexdigest())


@functools.lru_cache(maxsize=8)
def _compile(fmi_version: int, runtime: PythonRuntime, digest: str) -> bytes:
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_binary_") as tmp:
        output = Path(tmp) / "fmu.so"
        command = _command(fmi_version, runtime, output)
        try:
            run = subprocess.run(command, capture_output=True, text=True, timeout=600, env=_compiler_environment())
        except (OSError, subprocess.TimeoutExpired) as error:
            raise BinaryBuildError(f"compiling the FMU binary failed: {error}") from None
        if run.returncode != 0:
            detail = (run.stderr or run.stdout).strip().splitlines()
            raise BinaryBuildError(
                f"compiling the FMU binary failed ({' '.join(command[:4])} ...): {' | '.join(detail[-5:])}"
            )
        return output.read_bytes()
