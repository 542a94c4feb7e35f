"""libcosimpy is an extra: without it every function that needs it says so in one line (how to install it,
or that there is no wheel for this platform or Python), everything else imports and runs, and the tests
that need it follow one rule (``needs_libcosimpy``)."""

import dataclasses
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import dsc_fmu
from dsc_fmu.errors import DscFmuError
from dsc_fmu.interop import libcosim
from dsc_fmu.interop.libcosim_install import INSTALL, WHEELS, Interpreter, LibcosimUnavailableError, require_libcosimpy
from needs_libcosimpy import check_libcosimpy, libcosimpy  # noqa: F401 (the fixture)

REPO = Path(__file__).resolve().parents[1]
BLOCK = "import sys; sys.modules['libcosimpy'] = None; "  # makes `import libcosimpy` fail, as if not installed
HERE = Interpreter.current()
NOT_INSTALLED = "needs libcosimpy, which is not installed; install it with: python3 -m pip install 'dsc-fmu[libcosim]'"


def no_wheel(interpreter: Interpreter) -> str:
    return (f"needs libcosimpy, which has no wheel for {interpreter} (only for CPython 3.11-3.14 on x86-64 Linux "
            "with glibc 2.28 or newer and on 64-bit Windows), so it cannot be installed here; the rest of dsc-fmu "
            "works without it")


CPYTHON, LINUX, X86_64 = "CPython", "Linux", "x86_64"


@pytest.mark.parametrize("interpreter, has_wheel, shown", [
    (Interpreter(CPYTHON, (3, 11), LINUX, X86_64, (2, 36)), True, "CPython 3.11 on Linux x86_64 with glibc 2.36"),
    (Interpreter(CPYTHON, (3, 14), LINUX, X86_64, (2, 28)), True, "CPython 3.14 on Linux x86_64 with glibc 2.28"),
    (Interpreter(CPYTHON, (3, 14), "Windows", "AMD64"), True, "CPython 3.14 on Windows AMD64"),
    (Interpreter(CPYTHON, (3, 15), LINUX, X86_64, (2, 41)), False, "CPython 3.15 on Linux x86_64 with glibc 2.41"),
    (Interpreter(CPYTHON, (3, 10), LINUX, X86_64, (2, 36)), False, "CPython 3.10 on Linux x86_64 with glibc 2.36"),
    (Interpreter(CPYTHON, (3, 11), LINUX, X86_64, (2, 27)), False, "CPython 3.11 on Linux x86_64 with glibc 2.27"),
    (Interpreter(CPYTHON, (3, 11), LINUX, X86_64), False, "CPython 3.11 on Linux x86_64 without glibc"),
    (Interpreter(CPYTHON, (3, 11), LINUX, "aarch64", (2, 36)), False, "CPython 3.11 on Linux aarch64 with glibc 2.36"),
    (Interpreter(CPYTHON, (3, 12), "Darwin", "arm64"), False, "CPython 3.12 on macOS arm64"),
    (Interpreter(CPYTHON, (3, 12), "Darwin", X86_64), False, "CPython 3.12 on macOS x86_64"),
    (Interpreter(CPYTHON, (3, 12), "Windows", "ARM64"), False, "CPython 3.12 on Windows ARM64"),
    (Interpreter(CPYTHON, (3, 12), "Windows", "AMD64", bits=32), False, "CPython 3.12 (32-bit) on Windows AMD64"),
    (Interpreter("PyPy", (3, 11), LINUX, X86_64, (2, 36)), False, "PyPy 3.11 on Linux x86_64 with glibc 2.36"),
])
def test_where_libcosimpy_has_a_wheel(interpreter, has_wheel, shown):
    """libcosimpy 0.0.6's wheels: cp311-cp314, manylinux_2_28_x86_64 and win_amd64 (PyPI, 2026-12-07)."""
    assert interpreter.has_libcosimpy_wheel is has_wheel
    assert str(interpreter) == shown


def test_this_interpreter_is_read_from_the_system():
    import platform

    assert (HERE.implementation, HERE.version, HERE.system, HERE.machine) == (
        platform.python_implementation(), sys.version_info[:2], platform.system(), platform.machine())
    assert HERE.bits == 64 and (HERE.glibc is not None) == (platform.libc_ver()[0] == "glibc")


@pytest.mark.parametrize("interpreter, message", [
    (Interpreter("CPython", (3, 11), "Linux", "x86_64", (2, 36)), NOT_INSTALLED),
    (Interpreter("CPython", (3, 14), "Windows", "AMD64"), NOT_INSTALLED),
    (Interpreter("CPython", (3, 15), "Linux", "x86_64", (2, 41)),
     no_wheel(Interpreter("CPython", (3, 15), "Linux", "x86_64", (2, 41)))),
    (Interpreter("CPython", (3, 13), "Darwin", "arm64"), no_wheel(Interpreter("CPython", (3, 13), "Darwin", "arm64"))),
])
def test_the_message_says_how_to_get_it_or_that_there_is_none(monkeypatch, interpreter, message):
    monkeypatch.setitem(sys.modules, "libcosimpy", None)
    with pytest.raises(LibcosimUnavailableError) as missing:
        require_libcosimpy("run_libcosim", interpreter)
    assert str(missing.value) == f"run_libcosim {message}"
    assert isinstance(missing.value, DscFmuError) and isinstance(missing.value, ImportError)
    assert INSTALL in message or WHEELS in message


@pytest.mark.parametrize("function, arguments", [
    (libcosim.run_libcosim, ("paper.ssp", 1e-3, 0.01)),
    (libcosim.run_libcosim_fmu, ("MobileRobot.fmu", 1e-3, 0.01, ["x"])),
    (libcosim.run_libcosim_fmu_in_own_process, ("MobileRobot.fmu", 1e-3, 0.01, ["x"])),
])
def test_each_function_says_so_before_anything_else(monkeypatch, tmp_path, function, arguments):
    """Before it opens its file (none exists here) or starts a child."""
    monkeypatch.setitem(sys.modules, "libcosimpy", None)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(LibcosimUnavailableError) as missing:
        function(*arguments)
    expected = NOT_INSTALLED if HERE.has_libcosimpy_wheel else no_wheel(HERE)
    assert str(missing.value) == f"{function.__name__} {expected}"


@pytest.mark.parametrize("machine", [None, "aarch64"])
def test_the_command_line_says_so_in_one_line(tmp_path, machine):
    """``python -m dsc_fmu.interop.libcosim`` run as it is (runpy) in a child where libcosimpy does not import,
    on this machine and on one that reports itself as aarch64 (``platform.machine``), where it has no wheel."""
    pretend = f"import platform; platform.machine = lambda: {machine!r}; " if machine else ""
    code = (BLOCK + pretend
            + "import runpy; runpy.run_module('dsc_fmu.interop.libcosim', run_name='__main__', alter_sys=True)")
    out = tmp_path / "result.npy"
    child = subprocess.run([sys.executable, "-c", code, "MobileRobot.fmu", "0.001", "0.01", str(out), "--outputs", "x"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=120)
    there = dataclasses.replace(HERE, machine=machine) if machine else HERE
    expected = NOT_INSTALLED if there.has_libcosimpy_wheel else no_wheel(there)
    assert (child.returncode, child.stderr, child.stdout) == (
        1, f"dsc-fmu: error: python -m dsc_fmu.interop.libcosim {expected}\n", "")
    assert not out.exists()


def test_nothing_imports_libcosimpy_before_it_is_used():
    """Every module of the package, and the benchmark that uses libcosim, imported in a child: libcosimpy is
    not among the modules loaded (it is imported inside the functions that need it)."""
    modules = [info.name for info in pkgutil.walk_packages(dsc_fmu.__path__, "dsc_fmu.")
               if info.name != "dsc_fmu.__main__"]
    code = ("import importlib, json, runpy, sys\n"
            f"for name in {modules!r}: importlib.import_module(name)\n"
            f"runpy.run_path({str(REPO / 'benchmarks' / 'routes.py')!r}, run_name='routes')\n"
            "print(json.dumps(sorted(name for name in sys.modules if name.split('.')[0] == 'libcosimpy')))")
    child = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr[-2000:]
    assert "dsc_fmu.interop.libcosim" in modules
    assert json.loads(child.stdout.splitlines()[-1]) == []


def test_dsc_fmu_run_works_without_libcosimpy(fmu_paths, tmp_path):
    """The README's main job (``dsc-fmu run``, here short and without figures) in a child where libcosimpy
    does not import."""
    code = BLOCK + "from dsc_fmu.cli import main; sys.exit(main())"
    fmu_dir = Path(fmu_paths["MobileRobot"]).parent
    child = subprocess.run([sys.executable, "-c", code, "run", "figure_eight", "--stop-time", "0.05", "--no-plots",
                            "--quiet", "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "out")],
                           cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr[-2000:]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["settings"]["steps"] == 50


@pytest.mark.parametrize("interpreter, ci, outcome", [
    (Interpreter("CPython", (3, 11), "Linux", "x86_64", (2, 36)), None, pytest.fail.Exception),
    (Interpreter("CPython", (3, 11), "Linux", "x86_64", (2, 36)), "1", pytest.fail.Exception),
    (Interpreter("CPython", (3, 13), "Darwin", "arm64"), None, pytest.skip.Exception),
    (Interpreter("CPython", (3, 13), "Darwin", "arm64"), "1", pytest.fail.Exception),
])
def test_the_tests_skip_only_where_it_cannot_be_installed(monkeypatch, interpreter, ci, outcome):
    """``needs_libcosimpy``'s rule where libcosimpy does not import: fail where a wheel exists, skip where none
    does, fail under ``DSC_FMU_CI`` anyway; the reason is the package's message."""
    monkeypatch.setitem(sys.modules, "libcosimpy", None)
    if ci:
        monkeypatch.setenv("DSC_FMU_CI", ci)
    else:
        monkeypatch.delenv("DSC_FMU_CI", raising=False)
    with pytest.raises(outcome) as stopped:
        check_libcosimpy(interpreter)
    assert str(stopped.value.msg).startswith("this test needs libcosimpy, which ")


@pytest.mark.usefixtures("libcosimpy")
def test_the_tests_run_where_it_imports():
    check_libcosimpy(Interpreter("CPython", (3, 13), "Darwin", "arm64"))  # returns: installed is installed
