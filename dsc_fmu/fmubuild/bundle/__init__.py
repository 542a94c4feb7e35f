"""A CPython inside each FMU (``--bundle-python``; docs/fmus.md, "A CPython inside the FMU"): the building one's
for Linux of its CPU (``linux``), the official embeddable one for x86-64 Windows (``windows``), each with only the
standard-library modules the FMU's code imports (``modules``); other platforms use the importing machine's."""

from __future__ import annotations

import re
import sys
import tempfile
import zipfile
from pathlib import Path

from ..binary import WINDOWS, host_target
from .linux import linux_library, linux_refused, linux_runtime
from .modules import BundleError, imported_modules
from .runtime import MANIFEST, ROOT, Runtime
from .windows import windows_refused, windows_runtime

__all__ = ["BundleError", "ROOT"]

# The oldest CPython the FMUs' code runs on (``native/pyhost.c`` refuses older ones).
OLDEST_MINOR = 9


def bundle_minor(python: bool | str) -> int:
    """The minor version X of the Windows runtime that ``python`` asks for: True for the building CPython's, or
    ``"3.X"``; BundleError for anything else or older than 3.9.
    """
    if python is True:
        return sys.version_info.minor
    match = re.fullmatch(r"3\.(\d+)", str(python).strip())
    if not match or int(match.group(1)) < OLDEST_MINOR:
        raise BundleError(f"--bundle-python {python!r} is not a CPython version to bundle; allowed: 3.X with X "
                          f"{OLDEST_MINOR} or more (the building CPython's {sys.version_info.major}."
                          f"{sys.version_info.minor} if not given)")
    return int(match.group(1))


def carried_platforms(platforms) -> list[str]:
    """The platforms (FMI 3.0 tuples) that an FMU built here can carry a CPython for: x86-64 Windows, and this machine's
    Linux."""
    here = host_target()
    linux = here.name if here is not None and here.os == "linux" else None
    return [platform for platform in platforms if platform in (linux, WINDOWS.name)]


def bundled_runtimes(fmu: Path, entry: str, python: bool | str, platforms) -> dict:
    """The runtimes (by platform) that an FMU as the FMI library built it carries, for those of ``platforms`` it can.
    ``entry``: the modules the binary imports first, ``"<bridge module> <slave module>"``; ``python`` as in
    ``bundle_minor``. BundleError if one cannot be bundled (no shared library, no download, code that does not import).
    """
    minor = bundle_minor(python)
    carried = carried_platforms(platforms)
    linux = next((platform for platform in carried if platform.endswith("-linux")), None)
    windows = WINDOWS.name in carried
    if linux:
        linux_library()
    refused = (linux_refused() if linux else set()) | (windows_refused(minor) if windows else set())
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_bundle_") as tmp:
        with zipfile.ZipFile(fmu) as archive:
            archive.extractall(tmp, [name for name in archive.namelist() if name.startswith("resources/")])
        imports = imported_modules(Path(tmp) / "resources", entry, refused)
    runtimes = {}
    if linux:
        runtimes[linux] = linux_runtime(imports)
    if windows:
        runtimes[WINDOWS.name] = windows_runtime(minor, imports, whole_stdlib=minor != sys.version_info.minor)
    return runtimes
