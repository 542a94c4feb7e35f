"""``pip install .`` on every machine our users have: pip's resolver finds a wheel for every dependency (no
compiler needed), and the extra ``libcosim`` resolves exactly where ``libcosim_install`` says libcosimpy has one.

Each target is resolved as pip would install there: ``pip install --dry-run --ignore-installed
--only-binary=:all: --platform ... --python-version ... --implementation cp --report``, against PyPI alone
(``PIP_CONFIG_FILE=os.devnull`` and no ``PIP_*`` variables: no local index or wheel folder stands in for it). The
requirements are the project's as ``pyproject.toml`` declares them (the dependencies and the extra ``test``):
pip cannot resolve a source tree with ``--only-binary=:all:``, and the project itself is pure Python. pip
evaluates environment markers for the interpreter running it, not for ``--platform`` and ``--python-version``
(pypa/pip#11664), so a dependency behind ``sys_platform == "darwin"`` would go unchecked and one behind
``python_version < "3.12"`` would be checked for 3.15: the child sets the target's marker environment before pip
starts, and the report's ``environment`` shows that it took. The resolver is a recent pip's, run from its
wheel: pip 23 checks ``Requires-Python`` against the running interpreter in ``pip install``, not against
``--python-version``. Needs PyPI.
"""

import json
import os
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.utils import canonicalize_name

from dsc_fmu.interop.libcosim_install import Interpreter

pytestmark = pytest.mark.slow

PROJECT = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
REQUIREMENTS = [*PROJECT["dependencies"], *PROJECT["optional-dependencies"]["test"]]
LIBCOSIM = PROJECT["optional-dependencies"]["libcosim"]
PYPI = "https://pypi.org/simple"
PIP = "pip>=26"

# The pip of the wheel argv[1], with the target's marker environment (argv[2], JSON) in place of this interpreter's.
PIP_FOR_TARGET = (
    "import json, runpy, sys\n"
    "sys.path.insert(0, sys.argv.pop(1))\n"
    "from pip._vendor.packaging import markers\n"
    "target = {**markers.default_environment(), **json.loads(sys.argv.pop(1))}\n"
    "markers.default_environment = lambda: dict(target)\n"
    "runpy.run_module('pip', run_name='__main__', alter_sys=True)\n"
)


@dataclass(frozen=True)
class Target:
    """A machine to install on: its interpreter and the wheel platform tags pip accepts there."""

    interpreter: Interpreter
    platforms: tuple[str, ...]

    @property
    def markers(self) -> dict:
        """The marker environment pip would see there (PEP 508)."""
        version = "{}.{}".format(*self.interpreter.version)
        system = self.interpreter.system
        implementation = self.interpreter.implementation
        return {"implementation_name": implementation.lower(), "implementation_version": f"{version}.0",
                "os_name": "nt" if system == "Windows" else "posix", "platform_machine": self.interpreter.machine,
                "platform_python_implementation": implementation, "platform_system": system,
                "python_full_version": f"{version}.0", "python_version": version,
                "sys_platform": {"Linux": "linux", "Darwin": "darwin", "Windows": "win32"}[system]}


def macos(machine: str, python: tuple[int, int], version: int = 13) -> Target:
    """macOS ``version`` or newer: pip takes the wheels of that version and older ones (and universal2) itself.
    13 (Ventura) is the oldest that ziglang 0.17's wheels take."""
    return Target(Interpreter("CPython", python, "Darwin", machine), (f"macosx_{version}_0_{machine}",))


def linux(machine: str, python: tuple[int, int], glibc: tuple[int, int] = (2, 28)) -> Target:
    """Linux with ``glibc`` or newer (2.28: Debian 10, RHEL 8, Ubuntu 20.04): every manylinux tag it runs, as pip
    lists them on such a machine (``manylinux2014`` stands for 2.17; pip adds 2010 and 1 for x86_64)."""
    lowest = 5 if machine == "x86_64" else 17
    tags = tuple(f"manylinux_2_{minor}_{machine}" for minor in range(glibc[1], lowest - 1, -1))
    return Target(Interpreter("CPython", python, "Linux", machine, glibc), (*tags, f"manylinux2014_{machine}"))


TARGETS = {f"{name}-{python[0]}.{python[1]}": make(machine, python)
           for name, make, machine in [("macos-arm64", macos, "arm64"), ("macos-x86_64", macos, "x86_64"),
                                       ("linux-aarch64", linux, "aarch64"), ("linux-x86_64", linux, "x86_64")]
           for python in [(3, 11), (3, 15)]}


def pypi_only() -> dict:
    """This environment without pip's settings and configuration files: PyPI alone."""
    env = {name: value for name, value in os.environ.items() if not name.startswith("PIP_")}
    return {**env, "PIP_CONFIG_FILE": os.devnull, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}


@pytest.fixture(scope="session")
def pip_wheel(tmp_path_factory) -> Path:
    """The newest pip's wheel from PyPI (``PIP``), to run the resolver from."""
    folder = tmp_path_factory.mktemp("pip")
    command = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--index-url", PYPI,
               "--dest", str(folder), PIP]
    run = subprocess.run(command, env=pypi_only(), capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    (wheel,) = folder.glob("pip-*.whl")
    return wheel


def resolve(pip_wheel: Path, target: Target, requirements: list[str], report: Path) -> subprocess.CompletedProcess:
    """pip's resolver for ``target`` (dry run, wheels only, PyPI alone), its report written to ``report``."""
    platforms = [flag for tag in target.platforms for flag in ("--platform", tag)]
    command = [sys.executable, "-c", PIP_FOR_TARGET, str(pip_wheel), json.dumps(target.markers), "install",
               "--dry-run", "--ignore-installed", "--only-binary=:all:", *platforms, "--python-version",
               "{}.{}".format(*target.interpreter.version), "--implementation", "cp", "--index-url", PYPI,
               "--report", str(report), "--quiet", *requirements]
    return subprocess.run(command, env=pypi_only(), capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("name", TARGETS)
def test_every_dependency_is_a_wheel(name, pip_wheel, tmp_path):
    """Everything ``pip install ".[test]"`` installs there is a wheel from PyPI, and so is libcosimpy where
    ``libcosim_install`` says it has one (``pip install ".[test,libcosim]"``)."""
    target = TARGETS[name]
    assert SpecifierSet(PROJECT["requires-python"]).contains("{}.{}".format(*target.interpreter.version))
    requirements = REQUIREMENTS + (LIBCOSIM if target.interpreter.has_libcosimpy_wheel else [])
    report = tmp_path / "report.json"
    run = resolve(pip_wheel, target, requirements, report)
    assert run.returncode == 0, run.stderr[-3000:]
    found = json.loads(report.read_text())
    assert {key: found["environment"][key] for key in target.markers} == target.markers
    installs = found["install"]
    for item in installs:
        download = item["download_info"]
        assert download["url"].endswith(".whl") and "archive_info" in download, download["url"]
        assert not item["is_direct"], download["url"]
    names = {canonicalize_name(item["metadata"]["name"]) for item in installs}
    wanted = {canonicalize_name(r.name) for r in map(Requirement, requirements)
              if r.marker is None or r.marker.evaluate(target.markers)}
    assert wanted - names == set()
    assert ("libcosimpy" in names) is target.interpreter.has_libcosimpy_wheel


@pytest.mark.parametrize("name", [name for name, target in TARGETS.items()
                                  if not target.interpreter.has_libcosimpy_wheel])
def test_libcosim_has_no_wheel_there(name, pip_wheel, tmp_path):
    """Where ``libcosim_install`` says libcosimpy has no wheel, pip finds none: the extra is the right cut."""
    run = resolve(pip_wheel, TARGETS[name], LIBCOSIM, tmp_path / "report.json")
    assert run.returncode == 1
    assert "No matching distribution found for libcosimpy" in run.stderr, run.stderr[-3000:]


def test_libcosim_s_table_has_a_wheel_on_x86_64_linux_and_none_on_apple_silicon():
    """The extra libcosim resolves on x86-64 Linux with 3.11 and not on macOS arm64 (both resolved above)."""
    assert TARGETS["linux-x86_64-3.11"].interpreter.has_libcosimpy_wheel
    assert not TARGETS["macos-arm64-3.11"].interpreter.has_libcosimpy_wheel
