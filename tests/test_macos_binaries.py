"""The FMUs' macOS binaries, built and inspected, not run (no Mac here): folders, CPUs, exports, linked
libraries, minimum macOS, install names, the arm64 code signature, no build paths."""

from __future__ import annotations

import re
import tempfile
import zipfile
from pathlib import Path

import pytest

import dsc_fmu
from dsc_fmu.macho import read_slices

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
# Per FMI version, the macOS folders and the CPUs of their binary, in lipo's order. FMI 2.0 names darwin64
# only (one universal file); importers that know Apple Silicon also look in FMI 3.0's aarch64-darwin.
FOLDERS = {2: {"darwin64": ("x86_64", "arm64"), "aarch64-darwin": ("arm64",)},
           3: {"aarch64-darwin": ("arm64",), "x86_64-darwin": ("x86_64",)}}
MINIMUM_MACOS = {"arm64": "11.0", "x86_64": "10.13"}
FUNCTION_COUNTS = {2: 44, 3: 75}
LINKER_EXPORTS = {"___dso_handle", "__mh_dylib_header"}  # what Zig's linker exports from every dylib
FMUS = [(version, name) for version in FOLDERS for name in NAMES]
FILES = [(version, name, folder) for version in FOLDERS for name in NAMES for folder in FOLDERS[version]]
SLICES = [(version, name, folder, cpu) for version, name, folder in FILES for cpu in FOLDERS[version][folder]]
ARM64_SLICES = [case for case in SLICES if case[3] == "arm64"]


def _ids(cases: list[tuple]) -> list[str]:
    return ["-".join(map(str, case)) for case in cases]


def fmi_functions(version: int) -> set[str]:
    """The functions of FMI ``version`` as the standard's header declares them (FMPy's copy)."""
    import fmpy

    header = (Path(fmpy.__file__).parent / "c-code" / f"fmi{version}Functions.h").read_text()
    return set(re.findall(rf"^#define (fmi{version}\w+) +fmi{version}FullName", header, flags=re.M))


@pytest.fixture(scope="module")
def binaries(fmu_paths, fmu3_paths) -> dict[tuple[int, str, str], bytes]:
    """Every file in a macOS folder of the built FMUs, by (FMI version, FMU, path in the FMU)."""
    found = {}
    for version, paths in ((2, fmu_paths), (3, fmu3_paths)):
        for name, path in paths.items():
            with zipfile.ZipFile(path) as fmu:
                for item in fmu.namelist():
                    if re.fullmatch(r"binaries/[^/]*darwin[^/]*/.+", item):
                        found[version, name, item] = fmu.read(item)
    return found


def _dylib(binaries, version: int, name: str, folder: str) -> bytes:
    return binaries[version, name, f"binaries/{folder}/{name}.dylib"]


def _slice(binaries, version: int, name: str, folder: str, cpu: str):
    (found,) = [slice_ for slice_ in read_slices(_dylib(binaries, version, name, folder)) if slice_.cpu == cpu]
    return found


@pytest.mark.parametrize("version", FUNCTION_COUNTS)
def test_the_standard_header_declares_every_function(version):
    assert len(fmi_functions(version)) == FUNCTION_COUNTS[version]


@pytest.mark.parametrize(("version", "name"), FMUS, ids=_ids(FMUS))
def test_each_fmu_has_one_dylib_in_each_macos_folder(binaries, version, name):
    assert {item for v, n, item in binaries if (v, n) == (version, name)} == {
        f"binaries/{folder}/{name}.dylib" for folder in FOLDERS[version]}


@pytest.mark.parametrize(("version", "name", "folder"), FILES, ids=_ids(FILES))
def test_each_dylib_holds_its_folders_cpus(binaries, version, name, folder):
    slices = read_slices(_dylib(binaries, version, name, folder))
    assert [(slice_.cpu, slice_.file_type) for slice_ in slices] == [(cpu, "dylib") for cpu in FOLDERS[version][folder]]


@pytest.mark.parametrize("name", NAMES)
def test_the_universal_arm64_slice_is_the_aarch64_darwin_file(binaries, name):
    universal = _dylib(binaries, 2, name, "darwin64")
    arm64 = _slice(binaries, 2, name, "darwin64", "arm64")
    assert arm64.offset % 2**14 == 0
    assert universal[arm64.offset:arm64.offset + arm64.size] == _dylib(binaries, 2, name, "aarch64-darwin")


@pytest.mark.parametrize(("version", "name", "folder", "cpu"), SLICES, ids=_ids(SLICES))
def test_each_slice_exports_exactly_the_standards_functions(binaries, version, name, folder, cpu):
    exports = set(_slice(binaries, version, name, folder, cpu).exports)
    assert exports - LINKER_EXPORTS == {f"_{function}" for function in fmi_functions(version)}


@pytest.mark.parametrize(("version", "name", "folder", "cpu"), SLICES, ids=_ids(SLICES))
def test_each_slice_links_libsystem_only_and_names_itself_by_rpath(binaries, version, name, folder, cpu):
    slice_ = _slice(binaries, version, name, folder, cpu)
    assert slice_.dylibs == ("/usr/lib/libSystem.B.dylib",)
    assert slice_.install_name == f"@rpath/{name}.dylib"


@pytest.mark.parametrize(("version", "name", "folder", "cpu"), SLICES, ids=_ids(SLICES))
def test_each_slice_targets_the_oldest_macos_of_its_cpu(binaries, version, name, folder, cpu):
    assert _slice(binaries, version, name, folder, cpu).minos == MINIMUM_MACOS[cpu]


@pytest.mark.parametrize(("version", "name", "folder", "cpu"), ARM64_SLICES, ids=_ids(ARM64_SLICES))
def test_each_arm64_slice_is_signed_ad_hoc_with_valid_page_hashes(binaries, version, name, folder, cpu):
    signature = _slice(binaries, version, name, folder, cpu).signature
    assert signature is not None and signature.adhoc
    assert signature.pages_valid, f"code pages {signature.bad_pages} do not match their hashes"


@pytest.mark.parametrize(("version", "name", "folder"), FILES, ids=_ids(FILES))
def test_no_dylib_names_a_build_path(binaries, version, name, folder):
    """No temporary folder, Zig cache, home folder or checkout path inside (the symbol table is stripped)."""
    package = Path(dsc_fmu.__file__).resolve().parent
    paths = {"/tmp/", tempfile.gettempdir(), "/.cache/zig", "zig/o/", str(package), str(package.parent)}
    paths |= {str(Path.home())} - {"/"}
    data = _dylib(binaries, version, name, folder)
    assert sorted(path for path in paths if path.encode() in data) == []
