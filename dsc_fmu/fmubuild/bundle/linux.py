"""The Linux runtime (the building machine's CPU): the building CPython's shared library, the standard-library
modules the FMU's code imports as bytecode in ``lib/python3X.zip`` and its extension modules in
``lib/python3.X/lib-dynload`` (without debug sections): with the runtime's folder as home CPython finds them."""

from __future__ import annotations

import os
import platform
import sys
import sysconfig
from pathlib import Path

from ..binary import build_python, host_target
from .elf import needed, without_debug
from .modules import BundleError, Imports, building_stdlib
from .runtime import Runtime, bytecode, stored_zip

__all__ = []  # the runtime of ``bundle.bundled_runtimes`` for Linux

# The C runtime every glibc system has: extension modules that need nothing else are bundled freely.
GLIBC = ("libc.so.6", "libm.so.6", "libpthread.so.0", "libdl.so.2", "librt.so.1", "libutil.so.1",
         "ld-linux-x86-64.so.2", "ld-linux-aarch64.so.1")
_MINOR = f"{sys.version_info.major}.{sys.version_info.minor}"


def linux_library() -> Path:
    """The building CPython's ``libpython3.X.so.1.0``; ``BundleError`` (saying what provides one) if this is
    not Linux on a CPU of ``binary.TARGETS`` or the building CPython has none."""
    here = host_target()
    if here is None or here.os != "linux":
        raise BundleError(f"the Linux runtime is the building CPython's, and this is {sys.platform} on "
                          f"{platform.machine()}; allowed: build with --bundle-python on x86-64 or aarch64 Linux")
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
    """The building CPython's extension modules that need a library beyond glibc (OpenSSL's, zlib's, ...)."""
    dynload = building_stdlib()[1]
    suffix = sysconfig.get_config_var("EXT_SUFFIX")
    return {path.name[:-len(suffix)] for path in dynload.glob(f"*{suffix}") if _foreign(path)}


def _loaded(soname: str, mapped: tuple) -> Path:
    """The file of the library ``soname`` among the files a process had mapped."""
    for path in mapped:
        if path.name == soname or path.name.startswith(f"{soname}."):
            return path
    raise BundleError(f"{soname}, which a bundled extension module needs, was not loaded where the build imported "
                      f"the FMU's code; nothing was written")


def _licence(library: Path) -> bytes:
    """The licence of a system library: its Debian package's copyright file (found by file name, as a
    merged /usr lists /lib where the loader mapped /usr/lib), or ``/usr/share/licenses/<name>``."""
    real = library.resolve()
    for listing in Path("/var/lib/dpkg/info").glob("*.list"):
        if any(line.endswith(f"/{real.name}") for line in listing.read_text(errors="replace").splitlines()):
            copyright = Path("/usr/share/doc") / listing.stem.split(":")[0] / "copyright"
            if copyright.is_file():
                return copyright.read_bytes()
    stem = real.name.split(".so")[0]
    for name in (stem, stem.removeprefix("lib")):
        texts = sorted(p for p in (Path("/usr/share/licenses") / name).glob("*") if p.is_file())
        if texts:
            return b"\n".join(p.read_bytes() for p in texts)
    raise BundleError(f"no licence found for {real}, which a bundled extension module needs (looked for its "
                      f"Debian package's copyright and /usr/share/licenses/{stem}); nothing was written")


def linux_runtime(imports: Imports) -> Runtime:
    """The Linux runtime for code that imports ``imports``, needing the building machine's glibc or newer.

    The libraries beyond glibc that its extension modules need (zlib's for ``binascii``, libffi's for
    ``ctypes``, and theirs) go in ``lib/`` under their sonames with their licences; the binary loads them
    before CPython. ``BundleError`` as ``linux_library``, or for such a library or licence not found.
    """
    library = linux_library()
    stdlib = building_stdlib()[0]
    tag = _MINOR.replace(".", "")
    sources = {**imports.sources, **{f"encodings.{p.stem}": p for p in (stdlib / "encodings").glob("*.py")}}
    zipped = {}
    for name, path in sources.items():
        relative = path.relative_to(stdlib).with_suffix(".pyc").as_posix()
        zipped[relative] = bytecode(path.read_bytes(), f"{stdlib.name}/{relative[:-1]}", check_source=False)
    files = {f"lib/{library.name}": without_debug(library.read_bytes()), f"lib/python{tag}.zip": stored_zip(zipped)}
    licences = {"CPython": (stdlib / "LICENSE.txt").read_bytes()}
    pending = []
    for path in imports.extensions.values():
        files[f"lib/python{_MINOR}/lib-dynload/{path.name}"] = without_debug(path.read_bytes())
        pending += _foreign(path)
    while pending:
        soname = pending.pop()
        if f"lib/{soname}" not in files:
            path = _loaded(soname, imports.mapped)
            files[f"lib/{soname}"] = without_debug(path.read_bytes())
            licences[soname.split(".so")[0]] = _licence(path)
            pending += _foreign(path)
    needs = (f"{os.confstr('CS_GNU_LIBC_VERSION')} or newer",)
    return Runtime("linux", sys.version.split()[0], files, licences, needs)
