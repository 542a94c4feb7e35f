"""Mach-O files without a Mac: a universal (fat) file from thin 64-bit slices, as Apple's ``lipo`` makes it."""

from __future__ import annotations

import struct

__all__ = ["CPU_NAMES", "universal"]

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
    if magic == MH_MAGIC:
        raise ValueError(f"{what}: a 32-bit Mach-O; only 64-bit slices (magic 0x{MH_MAGIC_64:08x}) are allowed")
    if magic != MH_MAGIC_64:
        raise ValueError(f"{what}: not a thin 64-bit Mach-O (magic 0x{magic:08x}, allowed 0x{MH_MAGIC_64:08x})")
    return cputype, cpusubtype


def universal(slices: list[bytes]) -> bytes:
    """A universal Mach-O holding `slices` (thin 64-bit images, one per CPU), ordered by CPU type as lipo does.

    Raises ValueError for a slice that is no thin 64-bit Mach-O, or two slices of one CPU.
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
