"""The Linux x86-64 runtime: the building CPython's shared library, the standard-library modules the
FMU's code imports as bytecode in ``lib/python3X.zip``, and the extension modules it imports in
``lib/python3.X/lib-dynload`` (the libraries without their debug sections), so that with the runtime's
folder as its home CPython finds them itself."""

from __future__ import annotations

import os
import sys
import sysconfig
from pathlib import Path

from ..binary import build_python
from .elf import needed, without_debug
from .modules import BundleError, Imports, building_stdlib
from .runtime import Runtime, bytecode, stored_zip

__all__ = ["GLIBC", "linux_refused", "linux_runtime"]

# The libraries of the C runtime every glibc system has: extension modules that need nothing else are
# bundled freely.
GLIBC = ("libc.so.6", "libm.so.6", "libpthread.so.0", "libdl.so.2", "librt.so.1", "libutil.so.1",
         "ld-linux-x86-64.so.2")
_MINOR = f"{sys.version_info.major}.{sys.version_info.minor}"


def _library() -> Path:
    """The building CPython's shared library; refused in one line if it has none."""
    library = build_python().library
    if not library:
        raise BundleError(
            f"the building CPython ({sys.executable}) has no shared library libpython{_MINOR}.so.1.0 to bundle for "
            f"Linux; one comes with the distribution's libpython{_MINOR} package (Debian, Ubuntu) or python3-libs "
            f"(Fedora), or pyenv with PYTHON_CONFIGURE_OPTS=--enable-shared; nothing was written")
    return Path(library)


def _foreign(path: Path) -> list[str]:
    """The libraries the ELF file ``path`` needs beyond glibc and CPython's own library."""
    return [name for name in needed(path.read_bytes()) if name not in GLIBC and not name.startswith("libpython")]


def linux_refused() -> set[str]:
    """The extension modules of the building CPython that need a library beyond glibc.

    They (OpenSSL's, zlib's, libuuid's ...) are bundled only where an import cannot do without them.

    Returns
    -------
    set of str
        Their module names.

    Raises
    ------
    BundleError
        If the building CPython has no shared library.
    """
    _library()
    dynload = building_stdlib()[1]
    suffix = sysconfig.get_config_var("EXT_SUFFIX")
    return {path.name[:-len(suffix)] for path in dynload.glob(f"*{suffix}") if _foreign(path)}


def linux_runtime(imports: Imports) -> Runtime:
    """The Linux runtime for code that imports ``imports``.

    Parameters
    ----------
    imports : Imports
        What the FMU's code imports from the building CPython (``modules.imported_modules``).

    Returns
    -------
    Runtime
        Its files under the runtime's folder, CPython's licence, and what it needs of the system: the
        building machine's glibc or newer, and the libraries of any extension module an import needed.

    Raises
    ------
    BundleError
        If the building CPython has no shared library.
    """
    library = _library()
    stdlib = building_stdlib()[0]
    tag = _MINOR.replace(".", "")
    sources = {**imports.sources, **{f"encodings.{p.stem}": p for p in (stdlib / "encodings").glob("*.py")}}
    zipped = {}
    for name, path in sources.items():
        relative = path.relative_to(stdlib).with_suffix(".pyc").as_posix()
        zipped[relative] = bytecode(path.read_bytes(), f"{stdlib.name}/{relative[:-1]}", check_source=False)
    files = {f"lib/{library.name}": without_debug(library.read_bytes()), f"lib/python{tag}.zip": stored_zip(zipped)}
    needs = [f"{os.confstr('CS_GNU_LIBC_VERSION')} or newer"]
    for path in imports.extensions.values():
        files[f"lib/python{_MINOR}/lib-dynload/{path.name}"] = without_debug(path.read_bytes())
        needs += [name for name in _foreign(path) if name not in needs]
    return Runtime("linux", sys.version.split()[0], files, (stdlib / "LICENSE.txt").read_bytes(), tuple(needs))
