"""Where the FMUs' macOS binary looks for a CPython (``native/platform_macos.c``), tested as data on Linux,
not on a Mac: the seam's sources compiled for this machine with ``DSC_PLACES_ROOT`` naming a folder laid out
as a Mac (python.org's framework, Homebrew's on Apple Silicon and Intel, a conda environment, pyenv's
versions, Xcode's and the Command Line Tools' Python3.framework), and ``tests/c_macos_places.c`` printing
what the seam answers. That the binary loads and starts them is for a Mac to prove."""

import subprocess
import sys
from pathlib import Path

import pytest

from c_hosts import HERE
from dsc_fmu.fmubuild.binary import NATIVE_DIR

FRAMEWORK = "Library/Frameworks/Python.framework/Versions/3.{0}"
HOMEBREW_ARM = "opt/homebrew/opt/python@3.{0}/Frameworks/Python.framework/Versions/3.{0}"
HOMEBREW_INTEL = "usr/local/opt/python@3.{0}/Frameworks/Python.framework/Versions/3.{0}"
XCODE = "Applications/Xcode.app/Contents/Developer/Library/Frameworks/Python3.framework/Versions/3.{0}"
TOOLS = "Library/Developer/CommandLineTools/Library/Frameworks/Python3.framework/Versions/3.{0}"


def install(home: Path, minor: int, library: str) -> Path:
    """A CPython 3.``minor`` installation in ``home``: its library (``library``, relative) and standard library."""
    stdlib = home / "lib" / f"python3.{minor}"
    (stdlib / "encodings").mkdir(parents=True)
    (stdlib / "os.py").touch()
    (stdlib / "encodings" / "__init__.py").touch()
    (home / library).parent.mkdir(parents=True, exist_ok=True)
    (home / library).touch()
    return home / library


@pytest.fixture(scope="module")
def mac(tmp_path_factory):
    """A folder laid out as a Mac with one CPython in each installer's place, and the seam compiled for it."""
    root = tmp_path_factory.mktemp("mac")
    home = root / "Users" / "ada"
    libraries = {
        "python.org's": install(root / FRAMEWORK.format(13), 13, "Python"),
        "Homebrew's (Apple Silicon)": install(root / HOMEBREW_ARM.format(12), 12, "Python"),
        "Homebrew's (Intel)": install(root / HOMEBREW_INTEL.format(11), 11, "Python"),
        "Xcode's": install(root / XCODE.format(9), 9, "Python3"),
        "the Command Line Tools'": install(root / TOOLS.format(9), 9, "Python3"),
        "conda's": install(home / "miniforge3" / "envs" / "sim", 12, "lib/libpython3.12.dylib"),
        "pyenv 3.12.1": install(home / ".pyenv" / "versions" / "3.12.1", 12, "lib/libpython3.12.dylib"),
        "pyenv 3.12.9": install(home / ".pyenv" / "versions" / "3.12.9", 12, "lib/libpython3.12.dylib"),
        "pyenv 3.12.10": install(home / ".pyenv" / "versions" / "3.12.10", 12, "lib/libpython3.12.dylib"),
    }
    (home / ".pyenv" / "versions" / "3.11.9" / "bin").mkdir(parents=True)  # built without --enable-shared
    program = root / "c_macos_places"
    compiled = subprocess.run([
        sys.executable, "-m", "ziglang", "cc", "-O1", "-std=c11", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
        f"-I{NATIVE_DIR}", f'-DDSC_PLACES_ROOT="{root}"', str(NATIVE_DIR / "platform_posix.c"),
        str(NATIVE_DIR / "platform_macos.c"), str(HERE / "c_macos_places.c"), "-ldl", "-lpthread", "-o", str(program),
    ], capture_output=True, text=True, timeout=600)
    assert compiled.returncode == 0, compiled.stderr
    return root, home, program, libraries


def ask(program: Path, *arguments, env: dict | None = None) -> list[str]:
    run = subprocess.run([str(program), *map(str, arguments)], capture_output=True, text=True, timeout=60,
                         env=env or {"PATH": "/usr/bin:/bin"})
    assert run.returncode == 0, run.stderr
    return run.stdout.splitlines()


def test_every_installer_s_place_is_visited_newest_minor_first_then_the_loader_s_search(mac):
    """With conda's environment active and pyenv under HOME: each installed library once, by minor (newest
    first) and within a minor in the order python.org, Homebrew (Apple Silicon, Intel), conda, pyenv
    (newest version first, by its numbers), Xcode, the Command Line Tools; then libpython3.X.dylib for dyld's
    search, every minor from 3.20 down."""
    root, home, program, lib = mac
    env = {"PATH": "/usr/bin:/bin", "HOME": str(home), "CONDA_PREFIX": str(home / "miniforge3" / "envs" / "sim")}
    found = ask(program, "registered", 9, env=env)
    expected = [(13, "python.org's", "python.org's"), (12, "Homebrew's", "Homebrew's (Apple Silicon)"),
                (12, "conda's (CONDA_PREFIX)", "conda's"), (12, "pyenv's", "pyenv 3.12.10"),
                (12, "pyenv's", "pyenv 3.12.9"), (12, "pyenv's", "pyenv 3.12.1"), (11, "Homebrew's", "Homebrew's (Intel)"),
                (9, "Xcode's", "Xcode's"),
                (9, "the Command Line Tools'", "the Command Line Tools'")]
    assert found[:9] == [f"{minor} {label}|{lib[installer]}" for minor, label, installer in expected]
    assert found[9:] == [f"{minor} |libpython3.{minor}.dylib" for minor in range(20, 8, -1)]


def test_without_conda_or_home_only_the_fixed_places_and_pyenv_root(mac):
    """No CONDA_PREFIX, no HOME: conda's and ~/.pyenv are not looked at; PYENV_ROOT is, where set."""
    root, home, program, lib = mac
    found = ask(program, "registered", 12)
    assert [line.split("|")[0] for line in found if "|lib" not in line] == ["13 python.org's", "12 Homebrew's"]
    found = ask(program, "registered", 12, env={"PATH": "/usr/bin:/bin", "PYENV_ROOT": str(home / ".pyenv")})
    assert f"12 pyenv's|{lib['pyenv 3.12.10']}" in found and not any("conda" in line for line in found)


@pytest.mark.parametrize("installer, minor", [("python.org's", 13), ("Homebrew's (Apple Silicon)", 12), ("Xcode's", 9),
                                              ("conda's", 12), ("pyenv 3.12.10", 12)])
def test_the_home_is_the_nearest_folder_above_the_library_with_a_standard_library(mac, installer, minor):
    """A framework's Versions/3.X, an environment's or pyenv version's prefix."""
    root, home, program, lib = mac
    library = lib[installer]
    expected = library.parent.parent if library.parent.name == "lib" else library.parent
    assert ask(program, "home", library, minor) == [f"0 {expected}"]


def test_a_library_without_a_standard_library_above_it_is_refused(mac, tmp_path):
    root, home, program, lib = mac
    stray = tmp_path / "lib" / "libpython3.12.dylib"
    stray.parent.mkdir()
    stray.touch()
    assert ask(program, "home", stray, 12) == ["-1 no lib/python3.12 standard library above the library"]


@pytest.mark.parametrize("layout, minor, places", [
    ("framework version folder", 13, {0: "lib/libpython3.13.dylib", 1: "Python", 2: "Python3",
                                      3: "Frameworks/Python.framework/Versions/3.13/Python"}),
    ("another minor's version folder", 12, {0: "lib/libpython3.12.dylib", 1: "", 2: "",
                                            3: "Frameworks/Python.framework/Versions/3.12/Python"}),
])
def test_an_installation_folder_s_places(mac, layout, minor, places):
    """What DSC_FMU_PYTHON=<folder> and a virtual environment's home (its parent) are searched for: the
    framework's own library only where the folder is that minor's version folder."""
    root, home, program, lib = mac
    folder = root / FRAMEWORK.format(13)
    expected = [f"{place} {folder}/{path}" if path else f"{place} " for place, path in places.items()]
    assert ask(program, "in", folder, minor) == expected
