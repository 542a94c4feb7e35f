"""Mach-O files without a Mac: a universal (fat) file from thin 64-bit slices (as ``lipo``), and a reader."""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass

__all__ = ["CPU_NAMES"]  # ``fmubuild`` joins with ``universal``, the tests read with ``read_slices``

MH_MAGIC_64 = 0xFEEDFACF  # a thin 64-bit Mach-O, little-endian (x86_64 and arm64 both are)
MH_MAGIC = 0xFEEDFACE  # a thin 32-bit Mach-O
FAT_MAGIC = 0xCAFEBABE  # a universal file; its header and fat_arch entries are big-endian
FAT_ALIGN = 14  # each slice at a multiple of 2**14 bytes, as lipo puts arm64 slices
CPU_NAMES = {0x01000007: "x86_64", 0x0100000C: "arm64"}


def _thin_header(image: bytes, what: str) -> tuple[int, int]:
    """The (cputype, cpusubtype) of a thin 64-bit Mach-O image, or ValueError."""
    if len(image) < 32:
        raise ValueError(f"{what}: {len(image)} bytes, too short for a Mach-O header (32 bytes)")
    magic, cputype, cpusubtype = struct.unpack_from("<III", image)
    if struct.unpack_from(">I", image)[0] == FAT_MAGIC:
        raise ValueError(f"{what}: a universal file; only thin 64-bit Mach-O slices are allowed")
    if magic == MH_MAGIC:
        raise ValueError(f"{what}: a 32-bit Mach-O; only 64-bit slices (magic 0x{MH_MAGIC_64:08x}) are allowed")
    if magic != MH_MAGIC_64:
        raise ValueError(f"{what}: not a thin 64-bit Mach-O (magic 0x{magic:08x}, allowed 0x{MH_MAGIC_64:08x})")
    return cputype, cpusubtype


def universal(slices: list[bytes]) -> bytes:
    """Join thin 64-bit Mach-O images (one per CPU) into one universal file, ordered by CPU type as ``lipo`` does
    (x86_64 first): a big-endian ``0xcafebabe`` header, one ``fat_arch`` per slice, each slice at a multiple of
    2**14 bytes. ValueError for no slices, a slice that is no thin 64-bit Mach-O, or two slices of one CPU.
    """
    if not slices:
        raise ValueError("universal(): no slices; at least one thin 64-bit Mach-O is needed")
    headed = sorted((_thin_header(image, f"slice {i}"), image) for i, image in enumerate(slices))
    for ((cpu, _), _), ((next_cpu, _), _) in zip(headed, headed[1:]):
        if cpu == next_cpu:
            raise ValueError(f"two slices for CPU {CPU_NAMES.get(cpu, hex(cpu))}; one slice per CPU is allowed")
    alignment = 1 << FAT_ALIGN
    header = struct.pack(">II", FAT_MAGIC, len(headed))
    body = b""
    offset = len(header) + 20 * len(headed)
    for (cputype, cpusubtype), image in headed:
        padding = -offset % alignment
        offset += padding
        header += struct.pack(">IIIII", cputype, cpusubtype, offset, len(image), FAT_ALIGN)
        body += b"\0" * padding + image
        offset += len(image)
    return header + body


_FILE_TYPES = {1: "object", 2: "execute", 6: "dylib", 8: "bundle"}
LC_SYMTAB, LC_ID_DYLIB, LC_CODE_SIGNATURE, LC_BUILD_VERSION = 0x2, 0xD, 0x1D, 0x32
LC_VERSION_MIN_MACOSX, LC_DYLD_EXPORTS_TRIE = 0x24, 0x80000033
LC_DYLD_INFO = (0x22, 0x80000022)  # LC_DYLD_INFO, LC_DYLD_INFO_ONLY
# LC_LOAD_DYLIB, LC_LOAD_WEAK_DYLIB, LC_REEXPORT_DYLIB, LC_LAZY_LOAD_DYLIB, LC_LOAD_UPWARD_DYLIB
LC_LINKED_DYLIBS = (0xC, 0x80000018, 0x8000001F, 0x20, 0x80000023)
CSMAGIC_EMBEDDED_SIGNATURE, CSMAGIC_CODEDIRECTORY = 0xFADE0CC0, 0xFADE0C02
_PAGE_HASHES = {1: hashlib.sha1, 2: hashlib.sha256}  # CodeDirectory hashType -> hash


@dataclass(frozen=True)
class CodeSignature:
    """The CodeDirectory of a slice's embedded signature (``LC_CODE_SIGNATURE``), its page hashes checked.

    ``version`` (``0x20400`` is 2.4), ``flags`` (ad hoc ``0x2``, linker-signed ``0x20000``), ``hash_type`` (1 SHA-1,
    2 SHA-256); the code pages of ``page_size`` bytes cover the slice's bytes ``[0, code_limit)``, the last page may
    be short; ``bad_pages``: those whose stored hash differs from the hash of the slice's bytes.
    """

    version: int
    flags: int
    hash_type: int
    page_size: int
    code_limit: int
    identifier: str
    bad_pages: tuple[int, ...]

    @property
    def adhoc(self) -> bool:
        """Whether the signature is ad hoc (no certificate)."""
        return bool(self.flags & 0x2)

    @property
    def linker_signed(self) -> bool:
        """Whether the linker made the signature."""
        return bool(self.flags & 0x20000)

    @property
    def pages_valid(self) -> bool:
        """Whether every code page's stored hash matches the slice's bytes."""
        return not self.bad_pages


@dataclass(frozen=True)
class Slice:
    """One thin Mach-O image, alone or in a universal file.

    ``cpu``: ``"x86_64"``, ``"arm64"`` or the hexadecimal ``cputype``; ``file_type``: ``"dylib"``, ``"bundle"``,
    ``"execute"``, ``"object"`` or its hexadecimal number; ``offset`` and ``size`` in bytes in the data read (offset 0
    for a thin file); ``install_name`` from ``LC_ID_DYLIB``; ``dylibs``: the libraries it links (load, weak,
    re-export, lazy and upward ``LC_*_DYLIB``), in load-command order; ``minos``: the minimum macOS (``"11.0"``)
    from ``LC_BUILD_VERSION`` or ``LC_VERSION_MIN_MACOSX``; ``exports``: the exported symbols, sorted, as in the
    file (a C name with a leading ``_``), from the export trie, else the symbol table's external defined symbols;
    ``signature``: the embedded code signature, if any.
    """

    cpu: str
    file_type: str
    offset: int
    size: int
    install_name: str | None
    dylibs: tuple[str, ...]
    minos: str | None
    exports: tuple[str, ...]
    signature: CodeSignature | None


def _unpack(fmt: str, data: bytes, offset: int, what: str) -> tuple:
    end = offset + struct.calcsize(fmt)
    if offset < 0 or end > len(data):
        raise ValueError(f"truncated Mach-O: {what} needs bytes {offset}..{end}, there are {len(data)}")
    return struct.unpack_from(fmt, data, offset)


def _cstring(data: bytes, start: int, end: int, what: str) -> str:
    stop = data.find(b"\0", start, end)
    if start < 0 or stop < 0:
        raise ValueError(f"garbled Mach-O: {what} at {start} has no terminating NUL before {end}")
    return data[start:stop].decode("utf-8", "replace")


def _uleb128(data: bytes, pos: int, end: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= end:
            raise ValueError(f"truncated Mach-O: a ULEB128 number runs past the export trie's end ({end})")
        byte = data[pos]
        value |= (byte & 0x7F) << shift
        pos, shift = pos + 1, shift + 7
        if byte < 0x80:
            return value, pos


def _trie_exports(image: bytes, start: int, size: int) -> list[str]:
    """The names of the exports trie at image[start:start + size]: its nodes with terminal info."""
    end = start + size
    if end > len(image):
        raise ValueError(f"truncated Mach-O: the export trie ends at {end}, the slice at {len(image)}")
    names, stack, seen = [], [(0, "")], set()
    while size and stack:
        node, prefix = stack.pop()
        if node in seen or node >= size:
            raise ValueError(f"garbled Mach-O: export trie node {node} is out of range or reached twice")
        seen.add(node)
        terminal, pos = _uleb128(image, start + node, end)
        if terminal:
            names.append(prefix)
        pos += terminal
        (children,) = _unpack("B", image, pos, "an export trie node")
        pos += 1
        for _ in range(children):
            edge = _cstring(image, pos, end, "an export trie edge")
            child, pos = _uleb128(image, pos + len(edge.encode()) + 1, end)
            stack.append((child, prefix + edge))
    return names


def _symtab_exports(image: bytes, symoff: int, nsyms: int, stroff: int, strsize: int) -> list[str]:
    """The external defined symbols of the symbol table (nlist_64 entries)."""
    names = []
    for i in range(nsyms):
        strx, n_type = _unpack("<IB", image, symoff + 16 * i, "a symbol table entry")
        if not n_type & 0xE0 and n_type & 0x1 and n_type & 0xE:  # no stab, external, defined
            names.append(_cstring(image, stroff + strx, stroff + strsize, "a symbol name"))
    return names


def _signature(image: bytes, start: int, size: int) -> CodeSignature:
    """The CodeDirectory of the (big-endian) SuperBlob at image[start:start + size], its page hashes checked."""
    magic, _, count = _unpack(">III", image, start, "the code signature")
    if magic != CSMAGIC_EMBEDDED_SIGNATURE:
        raise ValueError(f"garbled Mach-O: code signature magic 0x{magic:08x},"
                         f" expected 0x{CSMAGIC_EMBEDDED_SIGNATURE:08x}")
    blobs = [_unpack(">II", image, start + 12 + 8 * i, "a signature blob index") for i in range(count)]
    directory = [start + offset for slot, offset in blobs if slot == 0]
    if not directory:
        raise ValueError("garbled Mach-O: the code signature has no CodeDirectory (slot 0)")
    cd = directory[0]
    (magic, _, version, flags, hash_offset, ident_offset, _, n_code, code_limit, hash_size, hash_type, _,
     page_log2) = _unpack(">7IIIBBBB", image, cd, "the CodeDirectory")
    if magic != CSMAGIC_CODEDIRECTORY:
        raise ValueError(f"garbled Mach-O: CodeDirectory magic 0x{magic:08x}, expected 0x{CSMAGIC_CODEDIRECTORY:08x}")
    if hash_type not in _PAGE_HASHES:
        raise ValueError(f"CodeDirectory hashType {hash_type}; only 1 (SHA-1) and 2 (SHA-256) are checked")
    hash_, page = _PAGE_HASHES[hash_type], 1 << page_log2
    if (code_limit > len(image) or n_code != -(-code_limit // page) or hash_size != hash_().digest_size
            or cd + hash_offset + n_code * hash_size > len(image)):
        raise ValueError(f"garbled Mach-O: {n_code} code hashes of {hash_size} bytes at {cd + hash_offset} for pages"
                         f" of {page} bytes up to {code_limit}, in a slice of {len(image)} bytes")
    bad = tuple(i for i in range(n_code)
                if hash_(image[i * page:min((i + 1) * page, code_limit)]).digest()
                != image[cd + hash_offset + i * hash_size:cd + hash_offset + (i + 1) * hash_size])
    identifier = _cstring(image, cd + ident_offset, start + size, "the signature identifier")
    return CodeSignature(version, flags, hash_type, page, code_limit, identifier, bad)


def _read_thin(image: bytes, offset: int, what: str) -> Slice:
    cputype, _ = _thin_header(image, what)
    file_type, ncmds, sizeofcmds = _unpack("<III", image, 12, "the Mach-O header")
    install_name = minos = signature = trie = symtab = None
    dylibs = []
    pos, end = 32, 32 + sizeofcmds
    for _ in range(ncmds):
        cmd, cmdsize = _unpack("<II", image, pos, "a load command")
        if cmdsize < 8 or pos + cmdsize > end:
            raise ValueError(f"garbled Mach-O: load command 0x{cmd:x} at {pos} of size {cmdsize} leaves the"
                             f" load commands (bytes 32..{end})")
        if cmd == LC_ID_DYLIB or cmd in LC_LINKED_DYLIBS:
            (name_offset,) = _unpack("<I", image, pos + 8, "a dylib command")
            name = _cstring(image, pos + name_offset, pos + cmdsize, "a dylib name")
            if cmd == LC_ID_DYLIB:
                install_name = name
            else:
                dylibs.append(name)
        elif cmd in (LC_BUILD_VERSION, LC_VERSION_MIN_MACOSX):
            (version,) = _unpack("<I", image, pos + (12 if cmd == LC_BUILD_VERSION else 8), "a version command")
            minos = f"{version >> 16}.{version >> 8 & 0xFF}" + (f".{version & 0xFF}" if version & 0xFF else "")
        elif cmd == LC_DYLD_EXPORTS_TRIE:
            trie = _unpack("<II", image, pos + 8, "the exports trie command")
        elif cmd in LC_DYLD_INFO:
            trie = _unpack("<II", image, pos + 40, "the dyld info command")
        elif cmd == LC_SYMTAB:
            symtab = _unpack("<IIII", image, pos + 8, "the symbol table command")
        elif cmd == LC_CODE_SIGNATURE:
            signature = _signature(image, *_unpack("<II", image, pos + 8, "the code signature command"))
        pos += cmdsize
    exports = _trie_exports(image, *trie) if trie else _symtab_exports(image, *symtab) if symtab else []
    return Slice(CPU_NAMES.get(cputype, f"0x{cputype:x}"), _FILE_TYPES.get(file_type, f"0x{file_type:x}"), offset,
                 len(image), install_name, tuple(dylibs), minos, tuple(sorted(exports)), signature)


def read_slices(data: bytes) -> list[Slice]:
    """The slices of a thin 64-bit or a universal Mach-O, in the file's order; ValueError for data that is no
    64-bit Mach-O or universal file, or truncated or garbled.
    """
    (magic,) = _unpack(">I", data, 0, "the magic number")
    if magic != FAT_MAGIC:
        return [_read_thin(data, 0, "the file")]
    (count,) = _unpack(">I", data, 4, "the universal header")
    slices = []
    for i in range(count):
        cputype, _, offset, size, _ = _unpack(">IIIII", data, 8 + 20 * i, f"fat_arch {i}")
        if offset + size > len(data):
            raise ValueError(f"truncated Mach-O: slice {i} needs bytes {offset}..{offset + size},"
                             f" there are {len(data)}")
        thin = _read_thin(data[offset:offset + size], offset, f"slice {i}")
        if thin.cpu != CPU_NAMES.get(cputype, f"0x{cputype:x}"):
            raise ValueError(f"garbled Mach-O: fat_arch {i} says CPU 0x{cputype:x}, its slice is {thin.cpu}")
        slices.append(thin)
    return slices
