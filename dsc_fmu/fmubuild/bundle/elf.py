"""What the Linux runtime needs to know of an x86-64 or aarch64 ELF shared library, read and cut in plain Python
(no binutils on a user's machine): the libraries it needs, and the file without its debug sections."""

from __future__ import annotations

import struct

from .modules import BundleError

__all__ = ["ElfError"]  # ``needed`` and ``without_debug`` serve ``bundle.linux``

_HEADER = struct.Struct("<16sHHIQQQIHHHHHH")  # Elf64_Ehdr
_SECTION = struct.Struct("<IIQQQQIIQQ")  # Elf64_Shdr
_PROGRAM = struct.Struct("<IIQQQQQQ")  # Elf64_Phdr
_DYNAMIC = struct.Struct("<qQ")  # Elf64_Dyn
_ALLOC, _NOBITS, _DYNAMIC_SECTION, _LOAD, _NEEDED, _STRTAB_TAG = 0x2, 8, 6, 1, 1, 5
_INFO_LINK = 0x40
_SHARED = 3  # e_type ET_DYN
_MACHINES = {62: "x86-64", 183: "aarch64"}  # e_machine EM_X86_64, EM_AARCH64


class ElfError(BundleError, ValueError):
    """The file is not an x86-64 or aarch64 ELF shared library this module can read or cut."""


def _header(data: bytes) -> tuple:
    if len(data) < _HEADER.size or data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        raise ElfError("not a 64-bit little-endian ELF file")
    header = _HEADER.unpack_from(data)
    if header[1] != _SHARED or header[2] not in _MACHINES:
        raise ElfError(f"not an x86-64 or aarch64 shared library (type {header[1]}, machine {header[2]})")
    return header


def _sections(data: bytes, header: tuple) -> list[list[int]]:
    offset, size, count = header[6], header[11], header[12]
    if size != _SECTION.size or offset + count * size > len(data):
        raise ElfError("its section header table is not inside the file")
    return [list(_SECTION.unpack_from(data, offset + i * size)) for i in range(count)]


def _string(data: bytes, offset: int) -> str:
    end = data.find(b"\0", offset)
    if end < 0:
        raise ElfError("a name of its dynamic section is not inside the file")
    return data[offset:end].decode("utf-8", "replace")


def needed(data: bytes) -> list[str]:
    """The sonames an ELF file names as DT_NEEDED, in order."""
    sections = _sections(data, _header(data))
    for kind, offset, size, link in ((s[1], s[4], s[5], s[6]) for s in sections):
        if kind != _DYNAMIC_SECTION:
            continue
        strings = sections[link][4]
        entries = (_DYNAMIC.unpack_from(data, offset + i) for i in range(0, size, _DYNAMIC.size))
        return [_string(data, strings + value) for tag, value in entries if tag == _NEEDED]
    return []


def without_debug(data: bytes) -> bytes:
    """A shared library without the sections a loader never reads (debug information, static symbols).

    What the program headers load is kept byte for byte, with the headers of the sections kept; ``data``
    itself if it has nothing to cut. ``ElfError`` unless its unloaded sections follow its loaded contents.
    """
    header = _header(data)
    sections = _sections(data, header)
    names = header[13]
    programs = [_PROGRAM.unpack_from(data, header[5] + i * header[9]) for i in range(header[10])]
    loaded_end = max([p[2] + p[5] for p in programs if p[0] == _LOAD] + [header[5] + header[9] * header[10]])
    keep = [i for i, s in enumerate(sections) if i == 0 or i == names or s[2] & _ALLOC]
    if len(keep) == len(sections):
        return data
    if any(s[4] + (0 if s[1] == _NOBITS else s[5]) > loaded_end for i, s in enumerate(sections)
           if i in keep and i not in (0, names)):
        raise ElfError("a loaded section lies beyond the loaded contents")
    index = {old: new for new, old in enumerate(keep)}
    out = bytearray(data[:loaded_end])
    start, size = sections[names][4], sections[names][5]
    sections[names][4] = len(out)
    out += data[start:start + size]
    out += bytes(-len(out) % 8)
    headers_at = len(out)
    for old in keep:
        section = sections[old]
        section[6] = index.get(section[6], 0)
        if section[2] & _INFO_LINK:
            section[7] = index.get(section[7], 0)
        out += _SECTION.pack(*section)
    fields = list(header)
    fields[6], fields[12], fields[13] = headers_at, len(keep), index[names]
    out[:_HEADER.size] = _HEADER.pack(*fields)
    return bytes(out)
