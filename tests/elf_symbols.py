"""The functions an ELF64 little-endian shared library imports: the undefined symbols of its ``.dynsym``."""

import struct
from pathlib import Path

SHT_DYNSYM = 11


def imported_functions(path: Path | str) -> set[str]:
    """The names of the undefined symbols of the library's dynamic symbol table (resolved at load time)."""
    data = Path(path).read_bytes()
    (table,) = struct.unpack_from("<Q", data, 0x28)
    entry, count = struct.unpack_from("<HH", data, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, table + i * entry) for i in range(count)]
    names = set()
    for _, kind, _, _, offset, size, link, _, _, symbol_size in sections:
        if kind != SHT_DYNSYM:
            continue
        strings = sections[link][4]
        for k in range(size // symbol_size):
            name, _, _, index = struct.unpack_from("<IBBH", data, offset + k * symbol_size)
            if index == 0 and name:
                names.add(data[strings + name:data.index(b"\0", strings + name)].decode())
    return names
