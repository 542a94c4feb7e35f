"""A CPython runtime as an FMU carries it beside its binary (docs/fmus.md, "A CPython inside the FMU"):
its files, the list the binary checks them by, its licence, what it still needs of the system."""

from __future__ import annotations

import importlib.util
import io
import marshal
import zipfile
from dataclasses import dataclass, field

__all__ = ["ROOT"]

# The runtime's folder beside the FMU's binary, and the file in it that lists the rest with their sizes
# (native/pyhost.c checks it before it loads anything).
ROOT = "python"
MANIFEST = "bundle.txt"


@dataclass(frozen=True)
class Runtime:
    """One platform's bundled CPython: the system it runs on (``"linux"``, ``"windows"``; its CPU is that of the
    folder it is carried in), its full version (``"3.11.7"``), its files by path under ``ROOT`` (the manifest
    excepted), the licences of what it carries by name (``"CPython"``, ``"libffi"``), and what it needs of the
    system beyond what the binary needs (``"glibc 2.36 or newer"``).
    """

    os: str
    version: str
    files: dict = field(repr=False)
    licences: dict = field(repr=False)
    needs: tuple = ()

    def manifest(self) -> bytes:
        """``MANIFEST``, which the binary checks the files by: ``dsc-fmu CPython <version> <os>``, then ``<size>
        <path>`` for each file."""
        lines = [f"dsc-fmu CPython {self.version} {self.os}"]
        lines += [f"{len(data)} {path}" for path, data in sorted(self.files.items())]
        return ("\n".join(lines) + "\n").encode()

    @property
    def size(self) -> int:
        """The bytes of its files."""
        return sum(len(data) for data in self.files.values())


def bytecode(source: bytes, filename: str, check_source: bool) -> bytes:
    """A ``.pyc`` file for the running CPython, hash-based (PEP 552): valid whatever the files' times;
    ``check_source``: an importer compares it with the source beside it."""
    flags = (0b11 if check_source else 0b01).to_bytes(4, "little")
    code = compile(source, filename, "exec", dont_inherit=True, optimize=0)
    return importlib.util.MAGIC_NUMBER + flags + importlib.util.source_hash(source) + marshal.dumps(code)


def stored_zip(entries: dict) -> bytes:
    """A reproducible zip of ``entries``, stored: zipimport needs no zlib, and the FMU's archive compresses it."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name in sorted(entries):
            archive.writestr(zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0)), entries[name])
    return buffer.getvalue()
