"""``dsc_fmu.macho`` on dylibs Zig compiles here for both Mac CPUs, checked against macholib."""

from __future__ import annotations

import dataclasses
import io
import struct
import subprocess
import sys

import pytest
from macholib import mach_o
from macholib.MachO import MachO

from dsc_fmu.macho import read_slices, universal

SOURCE = """\
#include <string.h>
static int probe_static(int x) { return x * 3; }
__attribute__((visibility("hidden"))) int probe_hidden(int x) { return x + 1; }
int probe_add(int a, int b) { return probe_static(a) + probe_hidden(b); }
size_t probe_length(const char *s) { return strlen(s); }
double probe_value = 2.5;
"""
EXPORTED = ("_probe_add", "_probe_length", "_probe_value")  # C names with the Mach-O leading '_'
INSTALL_NAME = "@rpath/libprobe.dylib"
MACHOLIB_CPUS = {cputype: name.lower() for cputype, name in mach_o.CPU_TYPE_NAMES.items()}
TARGETS = {"arm64": ("aarch64-macos.11.0", "11.0"), "x86_64": ("x86_64-macos.10.13", "10.13")}


@pytest.fixture(scope="module")
def thin(tmp_path_factory):
    """The probe library compiled for each Mac CPU, by CPU name: (file name, bytes)."""
    folder = tmp_path_factory.mktemp("macho")
    (folder / "probe.c").write_text(SOURCE)
    built = {}
    for cpu, (target, _) in TARGETS.items():
        output = folder / f"probe_{cpu}.dylib"
        _zig_dylib(target, f"-Wl,-install_name,{INSTALL_NAME}", str(folder / "probe.c"), "-o", str(output))
        built[cpu] = output.name, output.read_bytes()
    return built


def _zig_dylib(target: str, *arguments: str) -> None:
    """Compile and link a stripped macOS dylib with Zig."""
    subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", target, "-shared", "-fPIC", "-O2", "-s",
                    *arguments], check=True)


def _macholib_view(data: bytes, tmp_path) -> list[tuple]:
    """Per slice, what macholib reads: (CPU, offset, size, install names, linked dylibs, minos)."""
    path = tmp_path / "view.dylib"
    path.write_bytes(data)
    view = []
    for header in MachO(str(path), allow_unknown_load_commands=True).headers:
        names, linked, minos = [], [], None
        for load, command, payload in header.commands:
            if load.cmd in (mach_o.LC_ID_DYLIB, mach_o.LC_LOAD_DYLIB):
                name = payload[:payload.index(b"\0")].decode()
                (names if load.cmd == mach_o.LC_ID_DYLIB else linked).append(name)
            elif load.cmd in (mach_o.LC_BUILD_VERSION, mach_o.LC_VERSION_MIN_MACOSX):
                version = command.minos if load.cmd == mach_o.LC_BUILD_VERSION else command.version
                minos = f"{version >> 16}.{version >> 8 & 0xFF}"
        view.append((MACHOLIB_CPUS[header.header.cputype], header.offset, header.size, names, linked, minos))
    return view


@pytest.mark.parametrize("cpu", TARGETS)
def test_reader_reports_what_was_compiled(thin, cpu):
    (slice_,) = read_slices(thin[cpu][1])
    assert (slice_.cpu, slice_.file_type, slice_.offset, slice_.size) == (cpu, "dylib", 0, len(thin[cpu][1]))
    assert slice_.install_name == INSTALL_NAME
    assert slice_.dylibs == ("/usr/lib/libSystem.B.dylib",)
    assert slice_.minos == TARGETS[cpu][1]
    assert tuple(name for name in slice_.exports if name.startswith("_probe")) == EXPORTED


def test_reader_lists_weakly_linked_dylibs(tmp_path):
    (tmp_path / "other.c").write_text("int other(void) { return 1; }\n")
    (tmp_path / "user.c").write_text("int other(void);\nint user(void) { return other(); }\n")
    target = TARGETS["arm64"][0]
    _zig_dylib(target, "-Wl,-install_name,@rpath/libother.dylib", str(tmp_path / "other.c"), "-o",
               str(tmp_path / "libother.dylib"))
    _zig_dylib(target, f"-L{tmp_path}", "-weak-lother", str(tmp_path / "user.c"), "-o", str(tmp_path / "user.dylib"))
    (slice_,) = read_slices((tmp_path / "user.dylib").read_bytes())
    assert slice_.dylibs == ("/usr/lib/libSystem.B.dylib", "@rpath/libother.dylib")


@pytest.mark.parametrize("cpu", TARGETS)
def test_reader_agrees_with_macholib(thin, cpu, tmp_path):
    (slice_,) = read_slices(thin[cpu][1])
    assert _macholib_view(thin[cpu][1], tmp_path) == [
        (cpu, 0, slice_.size, [slice_.install_name], list(slice_.dylibs), slice_.minos)]


def test_arm64_is_signed_ad_hoc_by_the_linker_with_valid_page_hashes(thin):
    name, data = thin["arm64"]
    signature = read_slices(data)[0].signature
    assert signature.adhoc and signature.linker_signed
    assert (signature.hash_type, signature.page_size, signature.identifier) == (2, 2**14, name)
    assert signature.code_limit < len(data) and signature.pages_valid


def test_x86_64_is_not_signed(thin):
    assert read_slices(thin["x86_64"][1])[0].signature is None


@pytest.mark.parametrize("where", ["first page", "last (short) page"])
def test_a_flipped_byte_fails_its_page_hash(thin, where):
    data = bytearray(thin["arm64"][1])
    signature = read_slices(bytes(data))[0].signature
    position = 100 if where == "first page" else signature.code_limit - 1
    data[position] ^= 0xFF
    assert read_slices(bytes(data))[0].signature.bad_pages == (position // signature.page_size,)


@pytest.mark.parametrize("order", [("arm64", "x86_64"), ("x86_64", "arm64")])
def test_universal_holds_the_thin_files_byte_for_byte(thin, order):
    fat = universal([thin[cpu][1] for cpu in order])
    slices = read_slices(fat)
    assert [slice_.cpu for slice_ in slices] == ["x86_64", "arm64"]
    for slice_ in slices:
        assert slice_.offset % 2**14 == 0
        assert fat[slice_.offset:slice_.offset + slice_.size] == thin[slice_.cpu][1]
        assert slice_ == dataclasses.replace(read_slices(thin[slice_.cpu][1])[0], offset=slice_.offset)


def test_universal_header_as_macholib_reads_it(thin, tmp_path):
    fat = universal([thin["arm64"][1], thin["x86_64"][1]])
    stream = io.BytesIO(fat)
    header = mach_o.fat_header.from_fileobj(stream)
    archs = [mach_o.fat_arch.from_fileobj(stream) for _ in range(header.nfat_arch)]
    assert (header.magic, header.nfat_arch) == (mach_o.FAT_MAGIC, 2)
    assert [(MACHOLIB_CPUS[arch.cputype], arch.align) for arch in archs] == [("x86_64", 14), ("arm64", 14)]
    assert [arch.cpusubtype for arch in archs] == [struct.unpack_from("<I", thin[cpu][1], 8)[0]
                                                    for cpu in ("x86_64", "arm64")]
    expected = [view for cpu in ("x86_64", "arm64") for view in _macholib_view(thin[cpu][1], tmp_path)]
    assert [view[3:] for view in _macholib_view(fat, tmp_path)] == [view[3:] for view in expected]
    assert [view[1:3] for view in _macholib_view(fat, tmp_path)] == [(arch.offset, arch.size) for arch in archs]


def _as_32_bit(image: bytes) -> bytes:
    return struct.pack("<I", mach_o.MH_MAGIC) + image[4:]


@pytest.mark.parametrize(("slices", "message"), [
    (lambda thin: [], "no slices"),
    (lambda thin: [thin["arm64"][1], thin["arm64"][1]], "two slices for CPU arm64"),
    (lambda thin: [thin["x86_64"][1], SOURCE.encode()], r"slice 1: not a thin 64-bit Mach-O \(magic"),
    (lambda thin: [_as_32_bit(thin["x86_64"][1])], "slice 0: a 32-bit Mach-O; only 64-bit"),
    (lambda thin: [universal([thin["arm64"][1]])], "slice 0: a universal file; only thin"),
    (lambda thin: [b"\xcf\xfa\xed\xfe"], "slice 0: 4 bytes, too short"),
], ids=["none", "same CPU twice", "not Mach-O", "32-bit", "universal", "short"])
def test_universal_refuses(thin, slices, message):
    with pytest.raises(ValueError, match=message):
        universal(slices(thin))


def _garbled_signature(image: bytes) -> bytes:
    start = image.rindex(b"\xfa\xde\x0c\xc0")  # the SuperBlob's magic
    return image[:start] + b"\0\0\0\0" + image[start + 4:]


@pytest.mark.parametrize(("data", "message"), [
    (lambda thin: thin["arm64"][1][:100], "truncated Mach-O: a load command"),
    (lambda thin: b"\x7fELF" + bytes(60), r"the file: not a thin 64-bit Mach-O \(magic 0x464c457f"),
    (lambda thin: universal([thin["arm64"][1]])[:20000], "truncated Mach-O: slice 0 needs bytes 16384.."),
    (lambda thin: _garbled_signature(thin["arm64"][1]), "garbled Mach-O: code signature magic 0x00000000"),
    (lambda thin: b"\xca\xfe", "truncated Mach-O: the magic number"),
], ids=["cut in the load commands", "ELF", "cut universal", "signature", "two bytes"])
def test_reader_refuses(thin, data, message):
    with pytest.raises(ValueError, match=message):
        read_slices(data(thin))
