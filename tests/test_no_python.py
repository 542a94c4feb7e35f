"""The namespace without Python (``no_python.py``) really has none: no ``python*`` starts in it, no
``libpython3`` loads in it, and the default FMUs in the project's C importer (``env -i``) end at
instantiation with "no usable Python", as issue 27's first table row says, where outside they run."""

import os
import sys
from pathlib import Path

import pytest
from fmpy import extract, read_model_description

from c_hosts import EMPTY_ENVIRONMENT, compile_c, parse_rows, run_c
from no_python import BIN_FOLDERS, hidden, run_without_python

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
MINORS = range(0, 21)
PYTHON_NAMES = ("python", "python3", *(f"python3.{minor}" for minor in MINORS))
STEPS, STEP = 2, 0.02
REFUSAL = "no usable Python (CPython 3.9 or newer): "
TRY_EACH = 'for python in "$@"; do "$python" -c "import sys; print(\'started\', sys.argv[1])" "$python" || true; done'


def search_path() -> str:
    """This process's PATH and the usual bin folders, as one PATH."""
    folders = [*os.environ.get("PATH", "").split(os.pathsep), *BIN_FOLDERS]
    return os.pathsep.join(dict.fromkeys(f for f in folders if f))


def python_paths() -> list[str]:
    """Every ``python``, ``python3``, ``python3.X`` in the search path's folders, and the running interpreter."""
    found = [str(Path(folder) / name) for folder in search_path().split(os.pathsep) for name in PYTHON_NAMES
             if (Path(folder) / name).is_file()]
    return list(dict.fromkeys([sys.executable, getattr(sys, "_base_executable", sys.executable), *found]))


def started(run) -> list[str]:
    return [line.split(" ", 1)[1] for line in run.stdout.splitlines() if line.startswith("started ")]


def test_no_python_starts_in_the_namespace(tmp_path):
    """Each name on the search path and each path the machine has: outside the running interpreter and
    ``python3`` by name start; inside none does."""
    command = ["sh", "-c", TRY_EACH, "sh", *PYTHON_NAMES, *python_paths()]
    env = {**EMPTY_ENVIRONMENT, "PATH": search_path()}
    outside = run_c(command, tmp_path, env)
    assert {sys.executable, "python3"} <= set(started(outside)), outside.stderr
    inside = run_without_python(command, tmp_path, env)
    assert inside.returncode == 0 and started(inside) == [], inside.stdout


def libpython_paths() -> list[str]:
    """The shared ``libpython3*`` files of this machine: those the namespace covers, and those in the
    folders it covers."""
    what = hidden()
    in_folders = [p for folder in what.folders for p in folder.glob("**/libpython3*.so*")]
    return sorted({str(p) for p in [*what.files, *in_folders] if ".so" in p.name and p.is_file()})


def libpython_names() -> list[str]:
    """The names the loader is asked for: ``libpython3.so`` and, for each minor, the library's names."""
    forms = ("libpython3.{}.so.1.0", "libpython3.{}.so", "libpython3.{}m.so.1.0")
    return ["libpython3.so", *(form.format(minor) for minor in MINORS for form in forms)]


def loaded(run) -> list[str]:
    return [line.split(" ", 1)[1] for line in run.stdout.splitlines() if line.startswith("loaded ")]


def test_no_libpython_loads_in_the_namespace(tmp_path):
    """dlopen of every libpython name for 3.0 to 3.20 and of every libpython file found outside: outside
    every file and some name load, inside none does."""
    dlopen = compile_c("c_dlopen.c", tmp_path / "c_dlopen")
    paths = libpython_paths()
    command = [dlopen, *libpython_names(), *paths]
    outside = run_c(command, tmp_path)
    assert outside.returncode == 0, outside.stderr
    assert set(paths) <= set(loaded(outside)) and len(loaded(outside)) > len(paths), outside.stdout
    inside = run_without_python(command, tmp_path)
    assert inside.returncode == 0, inside.stderr
    assert loaded(inside) == [] and len(inside.stdout.splitlines()) == len(command) - 1, inside.stdout


@pytest.fixture(scope="module")
def importer(tmp_path_factory):
    return compile_c("c_importer.c", tmp_path_factory.mktemp("c") / "c_importer")


def importer_command(importer, version: int, path: Path, folder: Path) -> list:
    """``c_importer`` on the unzipped FMU ``folder`` (of ``path``): STEPS steps, its first output."""
    md = read_model_description(str(path))
    token = md.guid if version == 2 else md.instantiationToken
    output = next(v.valueReference for v in md.modelVariables if v.causality == "output")
    return [importer, version, folder, md.coSimulation.modelIdentifier, token, STEPS, STEP, output]


@pytest.mark.parametrize("version", (2, 3))
def test_the_default_fmus_find_no_python_in_the_namespace(importer, fmu_paths, fmu3_paths, tmp_path, version):
    """Issue 27's first row: each default FMU in the C importer with ``env -i``: outside it runs; inside
    it ends at instantiation (exit 2) with one message that no usable Python was found."""
    for name, path in (fmu3_paths if version == 3 else fmu_paths).items():
        folder = Path(extract(str(path), unzipdir=tmp_path / name))
        command = importer_command(importer, version, path, folder)
        outside = run_c(command, tmp_path)
        assert outside.returncode == 0 and len(parse_rows(outside.stdout)) == STEPS + 1, outside.stderr
        inside = run_without_python(command, tmp_path)
        errors = [line for line in inside.stderr.splitlines() if line.startswith("[")]
        assert inside.returncode == 2 and inside.stdout == "", inside.stderr
        assert len(errors) == 1 and REFUSAL in errors[0] and "the system's, not found: " in errors[0], inside.stderr
