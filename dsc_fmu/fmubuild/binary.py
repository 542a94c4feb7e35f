"""The FMUs' binary layer: ``native/`` compiled with Zig's C compiler (``ziglang``) for every platform, on any OS
(docs/fmus.md: no Python linked, any CPython from 3.9 found at run time, no system compiler or SDK needed)."""

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

from .. import platforms
from ..errors import DscFmuError
from ..platforms import Platform
from ..fmu.native_bridge import CAUSALITIES, TYPE_NAMES, TYPES, VARIABILITIES
from .emit_c import C_FLAGS

__all__ = ["BinaryBuildError", "TARGETS", "LINUX", "LINUX_AARCH64", "WINDOWS", "MACOS_ARM64", "MACOS_X86_64",
           "host_target", "OVERRIDE_VARIABLE"]

NATIVE_DIR = Path(__file__).parent / "native"
OVERRIDE_VARIABLE = "DSC_FMU_PYTHON"
# The file in an FMU's resources that names what the binary imports and creates:
# "<bridge module> <slave module> <slave class> <GUID or token>"; the bridge's top level is the
# build's private package.
ENTRY_FILE = "dsc_fmu_entry.txt"
# What the binaries of both versions share: the instance, the slave (by job), the resource URI, the Python.
_CORE = ("instance.c", "slave.c", "slave_queue.c", "slave_calls.c", "slave_values.c", "slave_states.c",
         "slave_traced.c", "uri.c", "pyhost.c")
_SOURCES = {2: ("fmi2Functions.c", *_CORE), 3: ("fmi3Functions.c", *_CORE)}
_HEADERS = ("adapter.h", "functions.h", "instance.h", "pyhost.h", "slave.h", "slave_calls.h", "uri.h", "platform.h",
            "traced.h", "traced_math.h")
# The C of an FMU whose model runs in Python only: the empty table of native/traced.h.
NO_TRACED_MODEL = '#include "traced.h"\n\nconst TracedModel TRACED_MODEL = {0};\n'
# How a model's traced C (traced_models.fmu_source) is compiled: bit for bit as CPython computes (C_FLAGS), its
# functions internal to the binary (only TRACED_MODEL is seen by the rest of it).
_TRACED_FLAGS = ("-O2", *C_FLAGS, "-DDSC_TRACED_API=static __attribute__((unused))", "-Wall", "-Wextra", "-Werror",
                 "-Wno-unused-parameter")


class BinaryBuildError(DscFmuError, RuntimeError):
    """The FMU binary could not be compiled; the message names the command and the compiler's output."""


@dataclass(frozen=True)
class Target(Platform):
    """A platform (``dsc_fmu.platforms``) and how its binary is compiled: Zig's target triple (with the oldest
    glibc or macOS the binary runs on), the platform seam's sources in ``native/`` (``platform.h``), compiler
    and linker flags, the libraries linked, and for macOS the name the binary gives itself (``{}``: the model
    identifier).
    """

    zig_target: str = ""
    platform_sources: tuple[str, ...] = ()
    flags: tuple[str, ...] = ()
    libraries: tuple[str, ...] = ()
    install_name: str = ""
    object_flags: tuple[str, ...] = ()


_POSIX = ("-fPIC", "-fvisibility=hidden")
# Every binary stripped (-s): on macOS the symbol table would name the objects in Zig's cache and the temporary output;
# everywhere the traced model's debug information would be most of the file (the controller's Linux binary: 2.5 MB,
# stripped 0.55 MB; 2026-12-07).
_STRIPPED = (*_POSIX, "-s")
_LINUX_SOURCES = ("platform_posix.c", "platform_linux.c")
_LINUX_LIBRARIES = ("-ldl", "-lpthread", "-lm")
_MACOS_SOURCES = ("platform_posix.c", "platform_macos.c")
LINUX = Target(**vars(platforms.LINUX), zig_target="x86_64-linux-gnu.2.17", platform_sources=_LINUX_SOURCES,
               flags=_STRIPPED, libraries=_LINUX_LIBRARIES, object_flags=_POSIX)
LINUX_AARCH64 = Target(**vars(platforms.LINUX_AARCH64), zig_target="aarch64-linux-gnu.2.17",
                       platform_sources=_LINUX_SOURCES, flags=_STRIPPED, libraries=_LINUX_LIBRARIES, object_flags=_POSIX)
WINDOWS = Target(**vars(platforms.WINDOWS), zig_target="x86_64-windows-gnu", platform_sources=("platform_windows.c",),
                 flags=("-s",))
MACOS_ARM64 = Target(**vars(platforms.MACOS_ARM64), zig_target="aarch64-macos.11.0", platform_sources=_MACOS_SOURCES,
                     flags=_STRIPPED, install_name="@rpath/{}.dylib", object_flags=_POSIX)
MACOS_X86_64 = Target(**vars(platforms.MACOS_X86_64), zig_target="x86_64-macos.10.13", platform_sources=_MACOS_SOURCES,
                      flags=_STRIPPED, install_name="@rpath/{}.dylib", object_flags=_POSIX)
TARGETS = (LINUX, LINUX_AARCH64, WINDOWS, MACOS_ARM64, MACOS_X86_64)


def host_target() -> Target | None:
    """The target of the machine this runs on.

    Returns
    -------
    Target or None
        One of ``TARGETS``, or None if the FMUs have no binary for this system and CPU.
    """
    here = platforms.host_platform()
    return next((target for target in TARGETS if here is not None and target.name == here.name), None)


@dataclass(frozen=True)
class PythonRuntime:
    """The Python a binary prefers (``native/pyhost.c`` has the order in which it looks): its version (``"3.11"``,
    whose candidates come first), the shared library and home (``sys.base_prefix``) of the Python that built
    it ("" for none or another platform), and the file name of the system's CPython libraries with ``%d``
    for the minor version ("": the platform's).
    """

    version: str
    library: str
    home: str
    system_name: str = ""


def build_python() -> PythonRuntime:
    """The running Python, which builds the FMUs: what a binary for this system looks for first after
    ``OVERRIDE_VARIABLE``."""
    library = ""
    if sys.platform == "win32":
        candidate = Path(sys.base_prefix) / f"python{sys.version_info.major}{sys.version_info.minor}.dll"
    elif sysconfig.get_config_var("PYTHONFRAMEWORK"):  # a macOS framework: INSTSONAME is Python.framework/...
        candidate = Path(sysconfig.get_config_var("PYTHONFRAMEWORKPREFIX") or "") / sysconfig.get_config_var("INSTSONAME")
    elif sysconfig.get_config_var("Py_ENABLE_SHARED"):
        candidate = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("INSTSONAME") or "")
    else:
        candidate = None
    if candidate is not None and candidate.is_file():
        # On macOS as found: Homebrew's opt/ path outlives the versioned Cellar folder it links to.
        library = str(candidate if sys.platform == "darwin" else candidate.resolve())
    return PythonRuntime(f"{sys.version_info.major}.{sys.version_info.minor}", library, sys.base_prefix)


def _runtime_for(target: Target, runtime: PythonRuntime) -> PythonRuntime:
    """What a binary for ``target`` may know of the building Python: its library only on the same platform."""
    return runtime if target == host_target() else PythonRuntime(runtime.version, "", "")


def binary_sources(fmi_version: int) -> list[Path]:
    """The sources and headers in ``native/`` of the binaries of one FMI version, for every target (not the standard's
    headers)."""
    seams = dict.fromkeys(name for target in TARGETS for name in target.platform_sources)
    return [NATIVE_DIR / name for name in (*_SOURCES[fmi_version], *seams, *_HEADERS)]


def _fmi_headers() -> Path:
    import fmpy

    return Path(fmpy.__file__).parent / "c-code"


def _c_string(text: str) -> str:
    return json.dumps(text)


def _status_category(status) -> str:
    """The log category pythonfmu's ``Fmi2Slave.log``, which owns the rule, gives a message of ``status``."""
    from pythonfmu import Fmi2Slave

    probe = SimpleNamespace(log_categories=Fmi2Slave.log_categories, log_queue=[])
    Fmi2Slave.log(probe, "", status)
    return probe.log_queue[0].category


def _log_categories() -> list[str]:
    """The defines of the declared log categories and of each status's, as pythonfmu gives them."""
    from pythonfmu import Fmi2Slave
    from pythonfmu.enums import Fmi2Status
    from pythonfmu3 import Fmi3Slave

    declared = list(Fmi2Slave.log_categories)
    if list(Fmi3Slave.log_categories) != declared:
        raise BinaryBuildError(f"pythonfmu and pythonfmu3 declare different log categories: {declared}, "
                               f"{list(Fmi3Slave.log_categories)}")
    by_status = [_status_category(status) for status in sorted(Fmi2Status)]
    return [f"-DDSC_LOG_CATEGORIES={_c_strings(declared)}", f"-DDSC_STATUS_CATEGORIES={_c_strings(by_status)}"]


def _c_strings(texts) -> str:
    return ", ".join(map(_c_string, texts))


def _contract(fmi_version: int) -> list[str]:
    """What the binary and the Python side agree on, owned by the Python side, as defines: the codes and type
    names of ``fmu/native_bridge.py`` (and the slave's get and set methods they name), the entry file, the
    environment variable that names a Python, the log categories."""
    tables = {"TYPE": TYPES, "CAUSALITY": CAUSALITIES, "VARIABILITY": VARIABILITIES}
    named = {(kind, code): name for kind, table in tables.items() for name, code in reversed(table.items())}
    values = [name.lower() for name in TYPE_NAMES[fmi_version][:-1]]  # String values are not supported
    return [
        *(f"-DDSC_{kind}_{name.upper()}={code}" for (kind, code), name in named.items()),
        f"-DDSC_TYPE_NAMES={_c_strings(TYPE_NAMES[fmi_version])}",
        f"-DDSC_GET_METHODS={_c_strings(f'get_{name}' for name in values)}",
        f"-DDSC_SET_METHODS={_c_strings(f'set_{name}' for name in values)}",
        f"-DDSC_ENTRY_FILE={_c_string(ENTRY_FILE)}",
        f"-DDSC_OVERRIDE_VARIABLE={_c_string(OVERRIDE_VARIABLE)}",
        *_log_categories(),
    ]


def _command(fmi_version: int, target: Target, runtime: PythonRuntime, output: Path, model_identifier: str,
             traced: Path) -> list[str]:
    install_name = [f"-Wl,-install_name,{target.install_name.format(model_identifier)}"] if target.install_name else []
    return [
        sys.executable, "-m", "ziglang", "cc", "-target", target.zig_target, "-shared", *target.flags, *install_name,
        "-O2", "-ffp-contract=off",
        "-std=c11", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
        f"-I{NATIVE_DIR}", f"-I{_fmi_headers()}",
        f"-DDSC_PYTHON_VERSION={_c_string(runtime.version)}",
        f"-DDSC_BUILD_LIBPYTHON={_c_string(runtime.library)}",
        f"-DDSC_BUILD_PYTHON_HOME={_c_string(runtime.home)}",
        *([f"-DDSC_SYSTEM_PYTHON={_c_string(runtime.system_name)}"] if runtime.system_name else []),
        *_contract(fmi_version),
        *(str(NATIVE_DIR / name) for name in (*_SOURCES[fmi_version], *target.platform_sources)), str(traced),
        "-o", str(output), *target.libraries,
    ]


def _compiler_environment() -> dict:
    """The environment for Zig, its cache in the temp folder where neither HOME nor XDG_CACHE_HOME is set."""
    env = dict(os.environ)
    if not any(env.get(key) for key in ("ZIG_GLOBAL_CACHE_DIR", "XDG_CACHE_HOME", "HOME")):
        env["ZIG_GLOBAL_CACHE_DIR"] = str(Path(tempfile.gettempdir()) / "dsc-fmu-zig-cache")
    return env


def compile_binary(fmi_version: int, target: Target = LINUX, runtime: PythonRuntime | None = None,
                   model_identifier: str = "", traced: str = NO_TRACED_MODEL) -> bytes:
    """The shared library of one FMI version for one platform, compiled once per process for the same inputs.
    ``runtime`` defaults to ``build_python()`` (its library only for this platform); ``model_identifier`` is required
    for a target whose binary names itself (``Target.install_name``); ``traced`` is the C of the FMU's model traced
    (``traced_models.fmu_source``; by default none: the model runs in Python). BinaryBuildError if the compiler
    cannot be run or fails, or a model identifier is missing.
    """
    if target.install_name and not model_identifier:
        raise BinaryBuildError(f"the {target.name} binary names itself after its FMU: give its model identifier")
    model_identifier = model_identifier if target.install_name else ""
    runtime = _runtime_for(target, runtime or build_python())
    digest = hashlib.sha256(repr((fmi_version, target, runtime, model_identifier, _contract(fmi_version))).encode())
    for path in binary_sources(fmi_version):
        digest.update(path.read_bytes())
    digest.update(traced.encode())
    return _compile(fmi_version, target, runtime, model_identifier, traced, digest.hexdigest())


# Zig's first compile for a platform also builds that platform's C library (MinGW's for Windows): 12 minutes
# on two emulated aarch64 cores.
COMPILE_TIMEOUT = 3600


def _run_zig(command: list, target: Target, what: str) -> None:
    """Run Zig's ``command``; BinaryBuildError, naming ``what`` and the compiler's last lines, if it fails."""
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=COMPILE_TIMEOUT,
                             env=_compiler_environment())
    except subprocess.TimeoutExpired:
        raise BinaryBuildError(
            f"compiling {what} for {target.name} took more than {COMPILE_TIMEOUT} s (Zig's first build for "
            "a platform compiles that platform's C library, kept in its cache): run the command again"
        ) from None
    except OSError as error:
        raise BinaryBuildError(f"compiling {what} for {target.name} failed: cannot run Zig: {error}") from None
    if run.returncode != 0:
        detail = (run.stderr or run.stdout).strip().splitlines()
        raise BinaryBuildError(
            f"compiling {what} for {target.name} failed ({' '.join(command[:6])} ...): {' | '.join(detail[-5:])}"
        )


def _traced_folder() -> Path:
    """Where traced C is written for Zig to compile: the user's cache folder (``XDG_CACHE_HOME`` or ``~/.cache``), or
    a folder of the user's own in the temp folder; readable and writable by the user only."""
    cache = os.environ.get("XDG_CACHE_HOME") or (os.path.join(os.environ["HOME"], ".cache") if os.environ.get("HOME")
                                                 else "")
    owner = str(os.getuid()) if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    folder = Path(cache) / "dsc-fmu" / "traced" if cache else Path(tempfile.gettempdir()) / f"dsc-fmu-traced-{owner}"
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    return folder


# The headers a traced model's C includes, written beside it.
_TRACED_HEADERS = ("traced.h", "traced_math.h")


def _write(path: Path, text: str) -> None:
    """``text`` into ``path`` unless it holds it already, replaced in one step."""
    if not path.is_file() or path.read_text() != text:
        with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp", delete=False) as staged:
            staged.write(text)
        os.replace(staged.name, path)


@functools.lru_cache(maxsize=32)
def _traced_object(target: Target, traced: str) -> bytes:
    """The object file of a traced model's C for ``target``. The C and the headers it includes are written into a
    folder named by their hash (``_traced_folder``), and nothing of the checkout's or the install's path enters the
    command: Zig caches an object by its source's path, content and command, so the same model compiles once per
    machine, whichever checkout or install builds it."""
    headers = {name: (NATIVE_DIR / name).read_text() for name in _TRACED_HEADERS}
    digest = hashlib.sha256(repr((traced, sorted(headers.items()))).encode()).hexdigest()[:32]
    folder = _traced_folder() / digest
    folder.mkdir(mode=0o700, exist_ok=True)
    for name, text in headers.items():
        _write(folder / name, text)
    _write(folder / "model.c", traced)
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_traced_") as tmp:
        output = Path(tmp) / "traced.o"
        _run_zig([sys.executable, "-m", "ziglang", "cc", "-target", target.zig_target, "-c", *target.object_flags,
                  *_TRACED_FLAGS, str(folder / "model.c"), "-o", str(output)], target, "the traced model")
        return output.read_bytes()


@functools.lru_cache(maxsize=32)
def _compile(fmi_version: int, target: Target, runtime: PythonRuntime, model_identifier: str, traced: str,
             digest: str) -> bytes:
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_binary_") as tmp:
        output = Path(tmp) / f"{model_identifier or 'fmu'}{target.suffix}"  # a signature's identifier is its name
        model = Path(tmp) / "traced.o"
        model.write_bytes(_traced_object(target, traced))
        command = _command(fmi_version, target, runtime, output, model_identifier, model)
        _run_zig(command, target, "the FMU binary")
        return output.read_bytes()
