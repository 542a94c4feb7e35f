"""The FMUs' binary layer: ``dsc_fmu/fmubuild/native`` compiled with Zig's C compiler (the ``ziglang`` package)
for x86-64 Linux and Windows, on any OS.

The binary replaces pythonfmu's and pythonfmu3's binaries in every FMU. It links no Python: it finds
one at run time (``native/pyhost.c``), so the FMUs load in C and C++ importers with no set-up, and any
CPython from 3.9 on runs them. Zig comes from the package index with everything it needs (a C
compiler, a linker, the glibc stubs and the MinGW-w64 import libraries), so building needs no system
compiler. The Linux binary targets glibc 2.17, so it also loads on distributions older than the one
that built it; the Windows binary imports KERNEL32 and the UCRT only.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from ..errors import DscFmuError
from ..fmu.native_bridge import CAUSALITIES, TYPES, VARIABILITIES

__all__ = [
    "BinaryBuildError", "PythonRuntime", "Target", "TARGETS", "LINUX", "WINDOWS", "build_python", "compile_binary",
    "binary_sources", "OVERRIDE_VARIABLE", "ENTRY_FILE",
]

NATIVE_DIR = Path(__file__).parent / "native"
OVERRIDE_VARIABLE = "DSC_FMU_PYTHON"
# The file in an FMU's resources that names what the binary imports and creates:
# "<bridge module> <slave module> <slave class> <GUID or token>"; the bridge's top level is the
# build's private package.
ENTRY_FILE = "dsc_fmu_entry.txt"
_SOURCES = {2: ("fmi2Functions.c", "instance.c", "slave.c", "pyhost.c"), 3: ("fmi3Functions.c", "instance.c", "slave.c", "pyhost.c")}
_HEADERS = ("adapter.h", "functions.h", "instance.h", "pyhost.h", "slave.h", "platform.h")


class BinaryBuildError(DscFmuError, RuntimeError):
    """The FMU binary could not be compiled (the message names the command and the compiler's output)."""


@dataclass(frozen=True)
class Target:
    """An OS the binary is built for: Zig's target, the FMI platform folders (FMI 2.0, 3.0), the file
    suffix, the platform seam's source and what it links."""

    os: str
    zig_target: str
    folders: tuple[str, str]
    suffix: str
    platform_source: str
    flags: tuple[str, ...]
    libraries: tuple[str, ...]

    def folder(self, fmi_version: int) -> str:
        """The FMI platform folder of the binary of FMI ``fmi_version``."""
        return self.folders[fmi_version - 2]

    def file(self, fmi_version: int, model_identifier: str) -> str:
        """The binary's path in an FMU."""
        return f"binaries/{self.folder(fmi_version)}/{model_identifier}{self.suffix}"


LINUX = Target("linux", "x86_64-linux-gnu.2.17", ("linux64", "x86_64-linux"), ".so", "platform_posix.c",
               ("-fPIC", "-fvisibility=hidden"), ("-ldl", "-lpthread", "-lm"))
WINDOWS = Target("windows", "x86_64-windows-gnu", ("win64", "x86_64-windows"), ".dll", "platform_windows.c", (), ())
TARGETS = (LINUX, WINDOWS)


@dataclass(frozen=True)
class PythonRuntime:
    """The Python the binary prefers: its minor version, the shared library (or "") and home of the
    Python that built it; ``system_name``, if not empty, the file name of the system's CPython
    libraries with ``%d`` for the minor version (default: ``libpython3.%d.so.1.0``, ``python3%d.dll``)."""

    version: str
    library: str
    home: str
    system_name: str = ""


def build_python() -> PythonRuntime:
    """The running Python: the one that builds the FMUs and that a binary for this OS looks for first
    after the override."""
    library = ""
    if sys.platform == "win32":
        candidate = Path(sys.base_prefix) / f"python{sys.version_info.major}{sys.version_info.minor}.dll"
    elif sysconfig.get_config_var("Py_ENABLE_SHARED"):
        candidate = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("INSTSONAME") or "")
    else:
        candidate = None
    if candidate is not None and candidate.is_file():
        library = str(candidate.resolve())
    return PythonRuntime(f"{sys.version_info.major}.{sys.version_info.minor}", library, sys.base_prefix)


def _runtime_for(target: Target, runtime: PythonRuntime) -> PythonRuntime:
    """What a binary for ``target`` may know of the building Python: its library only on the same OS."""
    here = "windows" if sys.platform == "win32" else sys.platform
    return runtime if target.os == here else PythonRuntime(runtime.version, "", "", runtime.system_name)


def binary_sources(fmi_version: int) -> list[Path]:
    """Every file the binaries of ``fmi_version`` are compiled from."""
    platforms = tuple(target.platform_source for target in TARGETS)
    return [NATIVE_DIR / name for name in (*_SOURCES[fmi_version], *platforms, *_HEADERS)]


def _fmi_headers() -> Path:
    """The FMI standard's headers, as FMPy ships them."""
    import fmpy

    return Path(fmpy.__file__).parent / "c-code"


def _c_string(text: str) -> str:
    return json.dumps(text)


def _status_category(status) -> str:
    """The log category pythonfmu gives a message of ``status`` (``Fmi2Slave.log``, which owns the rule)."""
    from pythonfmu import Fmi2Slave

    probe = SimpleNamespace(log_categories=Fmi2Slave.log_categories, log_queue=[])
    Fmi2Slave.log(probe, "", status)
    return probe.log_queue[0].category


def _log_categories() -> list[str]:
    """The log categories of the model descriptions and of each status, as pythonfmu writes and gives them."""
    from pythonfmu import Fmi2Slave
    from pythonfmu.enums import Fmi2Status
    from pythonfmu3 import Fmi3Slave

    declared = list(Fmi2Slave.log_categories)
    if list(Fmi3Slave.log_categories) != declared:
        raise BinaryBuildError(f"pythonfmu and pythonfmu3 declare different log categories: {declared}, "
                               f"{list(Fmi3Slave.log_categories)}")
    by_status = [_status_category(status) for status in sorted(Fmi2Status)]
    return [f"-DDSC_LOG_CATEGORIES={', '.join(map(_c_string, declared))}",
            f"-DDSC_STATUS_CATEGORIES={', '.join(map(_c_string, by_status))}"]


def _contract() -> list[str]:
    """What the binary and the Python side must agree on, owned by the Python side, as the defines
    ``slave.h`` takes: the codes of ``fmu/native_bridge.py``, the entry file, the log categories."""
    tables = {"TYPE": TYPES, "CAUSALITY": CAUSALITIES, "VARIABILITY": VARIABILITIES}
    named = {(kind, code): name for kind, table in tables.items() for name, code in reversed(table.items())}
    return [*(f"-DDSC_{kind}_{name.upper()}={code}" for (kind, code), name in named.items()),
            f"-DDSC_ENTRY_FILE={_c_string(ENTRY_FILE)}", *_log_categories()]


def _command(fmi_version: int, target: Target, runtime: PythonRuntime, output: Path) -> list[str]:
    return [
        sys.executable, "-m", "ziglang", "cc", "-target", target.zig_target, "-shared", *target.flags, "-O2",
        "-std=c11", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
        f"-I{NATIVE_DIR}", f"-I{_fmi_headers()}",
        f"-DDSC_PYTHON_VERSION={_c_string(runtime.version)}",
        f"-DDSC_BUILD_LIBPYTHON={_c_string(runtime.library)}",
        f"-DDSC_BUILD_PYTHON_HOME={_c_string(runtime.home)}",
        *([f"-DDSC_SYSTEM_PYTHON={_c_string(runtime.system_name)}"] if runtime.system_name else []),
        *_contract(),
        *(str(NATIVE_DIR / name) for name in (*_SOURCES[fmi_version], target.platform_source)),
        "-o", str(output), *target.libraries,
    ]


def _compiler_environment() -> dict:
    """The environment for Zig: it keeps its cache under HOME or XDG_CACHE_HOME; without either, in the temp folder."""
    env = dict(os.environ)
    if not any(env.get(key) for key in ("ZIG_GLOBAL_CACHE_DIR", "XDG_CACHE_HOME", "HOME")):
        env["ZIG_GLOBAL_CACHE_DIR"] = str(Path(tempfile.gettempdir()) / "dsc-fmu-zig-cache")
    return env


def compile_binary(fmi_version: int, target: Target = LINUX, runtime: PythonRuntime | None = None) -> bytes:
    """The shared library of the FMI ``fmi_version`` layer for ``target``, preferring ``runtime``
    (default: ``build_python()``, whose library a binary for another OS does not know)."""
    runtime = _runtime_for(target, runtime or build_python())
    digest = hashlib.sha256(repr((fmi_version, target, runtime, _contract())).encode())
    for path in binary_sources(fmi_version):
        digest.update(path.read_bytes())
    return _compile(fmi_version, target, runtime, digest.hexdigest())


@functools.lru_cache(maxsize=16)
def _compile(fmi_version: int, target: Target, runtime: PythonRuntime, digest: str) -> bytes:
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_binary_") as tmp:
        output = Path(tmp) / f"fmu{target.suffix}"
        command = _command(fmi_version, target, runtime, output)
        try:
            run = subprocess.run(command, capture_output=True, text=True, timeout=600, env=_compiler_environment())
        except (OSError, subprocess.TimeoutExpired) as error:
            raise BinaryBuildError(f"compiling the FMU binary failed: {error}") from None
        if run.returncode != 0:
            detail = (run.stderr or run.stdout).strip().splitlines()
            raise BinaryBuildError(
                f"compiling the FMU binary for {target.os} failed ({' '.join(command[:6])} ...): {' | '.join(detail[-5:])}"
            )
        return output.read_bytes()
