"""The binary layer on CPython's C API as CPython changes it (``native/pyhost.c``): adopting a running CPython
resolves only what it calls; starting one goes through PEP 741's ``PyInitConfig`` from 3.14 on and PEP 587's
``PyPreConfig``/``PyConfig`` before, whose per-version offsets are checked here against every version's own
header; no private name, deprecated setter or global flag is referenced; a build that treats every name
CPython removes or deprecates as absent still adopts and starts a CPython that has the replacement; a virtual
environment starts the version its ``pyvenv.cfg`` names."""

import json
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from fmpy import extract, read_model_description

from c_hosts import EMPTY_ENVIRONMENT, HERE, compile_c, parse_rows
from test_c_importer import STEP, STEPS, c_run, cpython_home, outputs as real_outputs, shared_cpython
from wine import required
from dsc_fmu.fmubuild.binary import (ENTRY_FILE, LINUX, NATIVE_DIR, OVERRIDE_VARIABLE, TARGETS, PythonRuntime,
                                     build_python, compile_binary)

LAYOUT_MINORS = (9, 10, 11, 12, 13)  # started through PyConfig, whose layout changes with every minor version
LAYOUT_FIELDS = ("PARSE_ARGV", "SITE_IMPORT", "WRITE_BYTECODE", "USER_SITE_DIRECTORY", "CONFIG_C_STDIO", "HOME")
UTF8_MODE = {"windows": 8, "other": 7}  # PyPreConfig's int fields before utf8_mode (Windows has one more)
# Names CPython has removed or deprecated where a replacement exists, and private ones: never referenced.
NEVER = ("_PyConfig_InitCompatConfig", "Py_SetPythonHome", "Py_SetProgramName", "Py_SetPath", "PySys_SetArgv",
         "PySys_SetArgvEx", "Py_GetPythonHome", "Py_GetPath", "Py_GetPrefix", "Py_GetProgramName",
         "Py_InitializeEx", "PyEval_InitThreads", "Py_IgnoreEnvironmentFlag", "Py_NoSiteFlag",
         "Py_NoUserSiteDirectory", "Py_DontWriteBytecodeFlag", "Py_IsolatedFlag", "Py_UTF8Mode", "Py_VerboseFlag",
         "Py_FrozenFlag", "Py_OptimizeFlag", "Py_UnbufferedStdioFlag", "Py_HashRandomizationFlag",
         "Py_LegacyWindowsFSEncodingFlag", "Py_FileSystemDefaultEncoding")
# Used only where the CPython lacks the replacement: PyErr_GetRaisedException (3.12), Py_GetConstantBorrowed and
# Py_IsFinalizing (3.13).
OLDER_ONLY = ("PyErr_Fetch", "PyErr_Restore", "PyErr_NormalizeException", "_Py_NoneStruct", "_Py_IsFinalizing")


def pyhost_layouts() -> dict:
    """``CONFIG_LAYOUTS`` of pyhost.c: {"windows" | "other": {minor: (offsets in LAYOUT_FIELDS' order)}}."""
    source = (NATIVE_DIR / "pyhost.c").read_text()
    match = re.search(r"#ifdef _WIN32\n(static const ConfigLayout CONFIG_LAYOUTS.*?\n};)\n#else\n"
                      r"(static const ConfigLayout CONFIG_LAYOUTS.*?\n};)\n#endif", source, re.S)
    assert match, "pyhost.c keeps no CONFIG_LAYOUTS for Windows and the others"

    def table(text):
        return {int(minor): tuple(int(n) for n in numbers.split(","))
                for minor, numbers in re.findall(r"\[(\d+)\] = \{([\d, ]+)\}", text)}

    return {"windows": table(match[1]), "other": table(match[2])}


def cpython_headers(minor: int) -> Path:
    """The folder of CPython 3.``minor``'s headers (``include/python3.X``) on this machine."""
    folder = cpython_home(minor) / "include" / f"python3.{minor}"
    if not (folder / "cpython" / "initconfig.h").is_file():
        required(f"no headers of CPython 3.{minor} in {folder}")
    return folder


@pytest.mark.parametrize("minor", LAYOUT_MINORS, ids=lambda minor: f"3.{minor}")
def test_the_pyconfig_offsets_are_each_versions_own_on_every_platform(minor, tmp_path):
    """pyhost.c's offsets of 3.``minor``, compiled against that version's header for every platform the FMUs
    carry (each ``_Static_assert`` of ``c_config_layout.c`` holds)."""
    layouts, headers = pyhost_layouts(), cpython_headers(minor)
    for target in TARGETS:
        kind = "windows" if target.os == "windows" else "other"
        fields = dict(zip(LAYOUT_FIELDS, layouts[kind][minor]), UTF8_MODE=UTF8_MODE[kind])
        run = subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", target.zig_target.split(".2.")[0],
                              "-c", "-o", str(tmp_path / "layout.o"), f"-I{headers}",
                              *(f"-D{k}={v}" for k, v in fields.items()),
                              str(HERE / "c_config_layout.c")], capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, f"{target.name}, CPython 3.{minor}: {run.stderr[-1500:]}"


@pytest.mark.parametrize("target", TARGETS, ids=lambda target: target.name)
def test_no_binary_references_a_removed_deprecated_or_private_name(target):
    """Each platform's binary, FMI 2.0 and 3.0: none of ``NEVER``; the older names only beside their
    replacements, which the binary prefers."""
    for version in (2, 3):
        binary = compile_binary(version, target, model_identifier="Robot")
        referenced = {name for name in (*NEVER, *OLDER_ONLY) if name.encode() + b"\0" in binary}
        assert referenced == set(OLDER_ONLY), (target.name, version, referenced)
        for newer in ("PyErr_GetRaisedException", "Py_GetConstantBorrowed", "Py_IsFinalizing", "PyInitConfig_Create"):
            assert newer.encode() + b"\0" in binary, (target.name, version, newer)


def absent_build(names) -> bytes:
    """The Linux FMI 2.0 binary built to treat ``names`` as absent from every CPython (``DSC_ABSENT_SYMBOLS``)."""
    target = replace(LINUX, flags=(*LINUX.flags, f'-DDSC_ABSENT_SYMBOLS="{" ".join(names)}"'))
    return compile_binary(2, target)


@pytest.fixture(scope="module")
def importer(tmp_path_factory):
    return compile_c("c_importer.c", tmp_path_factory.mktemp("c") / "c_importer")


def controller(fmu_paths, folder: Path, binary: bytes | None = None):
    """DSCController (FMI 2.0) unzipped into ``folder``, with ``binary`` in place of its own if given; its
    description and its output references."""
    md = read_model_description(str(fmu_paths["DSCController"]))
    extract(str(fmu_paths["DSCController"]), unzipdir=folder)
    if binary is not None:
        (folder / LINUX.file(2, "DSCController")).write_bytes(binary)
    return md, real_outputs(md)


def test_without_every_removed_and_deprecated_name_a_cpython_with_the_replacements_starts(importer, fmu_paths,
                                                                                          tmp_path):
    """The absent build starts CPython 3.13 (PyConfig, PyErr_GetRaisedException, Py_GetConstantBorrowed) and gives
    the default build's rows; CPython 3.11, which has no PyErr_GetRaisedException, is refused in one line that
    names the symbol, the version and the library."""
    md, outputs = controller(fmu_paths, tmp_path / "default")
    absent = tmp_path / "absent"
    controller(fmu_paths, absent, absent_build((*NEVER, *OLDER_ONLY)))
    expected = c_run(importer, 2, tmp_path / "default", md, outputs, tmp_path)
    newer = c_run(importer, 2, absent, md, outputs, tmp_path,
                  {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: str(shared_cpython(13))})
    assert expected.returncode == 0 and newer.returncode == 0, newer.stderr
    assert parse_rows(newer.stdout) == parse_rows(expected.stdout)
    built = build_python()
    older = c_run(importer, 2, absent, md, outputs, tmp_path, {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: built.library})
    assert older.returncode == 2, older.stderr
    (message,) = [line for line in older.stderr.splitlines() if line.startswith("[")]
    assert (f"{OVERRIDE_VARIABLE} = {built.library}: CPython {built.version}" in message
            and f"in {Path(built.library).resolve()} has no symbol PyErr_Fetch" in message), message


ADOPT = r"""
import importlib.util, json, sys
spec = importlib.util.spec_from_file_location("fmi_ctypes", sys.argv[1])
driver = importlib.util.module_from_spec(spec)
spec.loader.exec_module(driver)
slave = driver.Fmi2Slave(sys.argv[2])
names = sys.argv[3].split(",")
slave.instantiate()
slave.setup_experiment()
slave.enter_initialization_mode()
slave.exit_initialization_mode()
step = float(sys.argv[5])
rows = [[0.0, *slave.get_real(names)]]
for k in range(int(sys.argv[4])):
    slave.do_step(k * step, step)
    rows.append([(k + 1) * step, *slave.get_real(names)])
slave.terminate()
print(json.dumps({"version": sys.version.split()[0], "rows": rows}))
"""


def adopted_rows(python: str, folder: Path, md, tmp_path) -> dict:
    """DSCController in ``folder`` run through ctypes inside ``python`` (which the binary adopts): its rows as
    the C importer prints them, and the version of ``python``."""
    by_reference = {v.valueReference: v.name for v in md.modelVariables}
    names = ",".join(by_reference[int(reference)] for reference in real_outputs(md))
    run = subprocess.run([python, "-I", "-c", ADOPT, str(HERE / "fmi_ctypes.py"), str(folder), names, str(STEPS),
                          repr(STEP)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.splitlines()[-1])


def test_without_every_removed_and_deprecated_name_a_running_cpython_with_the_replacements_is_adopted(
        importer, fmu_paths, tmp_path):
    """The absent build inside CPython 3.13 (as fmpy's or PyFMI's process holds one): the rows of the default
    build in the C importer."""
    md, outputs = controller(fmu_paths, tmp_path / "default")
    absent = tmp_path / "absent"
    controller(fmu_paths, absent, absent_build((*NEVER, *OLDER_ONLY)))
    expected = c_run(importer, 2, tmp_path / "default", md, outputs, tmp_path)
    python = cpython_home(13) / "bin" / "python3.13"
    adopted = adopted_rows(str(python), absent, md, tmp_path)
    assert adopted["version"].startswith("3.13.")
    assert adopted["rows"] == parse_rows(expected.stdout)


def two_versions(folder: Path) -> Path:
    """An installation folder that holds CPython 3.12 and 3.13: each one's library and standard library linked
    into its ``lib``, and a ``bin`` for a virtual environment's ``home``."""
    (folder / "lib").mkdir(parents=True)
    (folder / "bin").mkdir()
    for minor in (12, 13):
        (folder / "lib" / f"libpython3.{minor}.so.1.0").symlink_to(shared_cpython(minor))
        (folder / "lib" / f"python3.{minor}").symlink_to(cpython_home(minor) / "lib" / f"python3.{minor}")
    return folder


def loaded_pythons(stderr: str) -> set[str]:
    """The CPython libraries the dynamic loader opened (``LD_DEBUG=files``)."""
    return set(re.findall(r"file=\S*/(libpython3\.\d+\.so\.1\.0)", stderr))


@pytest.mark.parametrize("written", ("version = 3.12.1", "version_info = 3.12.1.final.0"),
                         ids=("venv", "virtualenv"))
def test_a_virtual_environment_starts_its_own_version_where_its_home_holds_two(importer, fmu_paths, tmp_path,
                                                                                written):
    """A virtual environment of 3.12 (as the venv module and virtualenv write pyvenv.cfg) whose home also holds
    3.13: 3.12 is the only CPython loaded, and the rows are the building CPython's."""
    home = two_versions(tmp_path / "home")
    venv = tmp_path / "venv"
    venv.mkdir()
    (venv / "pyvenv.cfg").write_text(f"home = {home / 'bin'}\ninclude-system-site-packages = false\n{written}\n")
    md, outputs = controller(fmu_paths, tmp_path / "c")
    expected = c_run(importer, 2, tmp_path / "c", md, outputs, tmp_path)
    run = c_run(importer, 2, tmp_path / "c", md, outputs, tmp_path,
                {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: str(venv), "LD_DEBUG": "files"})
    assert run.returncode == 0, run.stderr[-2000:]
    assert loaded_pythons(run.stderr) == {"libpython3.12.so.1.0"}
    assert parse_rows(run.stdout) == parse_rows(expected.stdout)


def test_a_virtual_environment_whose_version_its_home_lacks_is_one_message(importer, fmu_paths, tmp_path):
    """A virtual environment of 3.10 over the home of 3.12 and 3.13: neither is started, and the one message
    names the environment, its version and where the library was looked for."""
    home = two_versions(tmp_path / "home")
    venv = tmp_path / "venv"
    venv.mkdir()
    (venv / "pyvenv.cfg").write_text(f"home = {home / 'bin'}\nversion = 3.10.13\n")
    md, outputs = controller(fmu_paths, tmp_path / "c")
    run = c_run(importer, 2, tmp_path / "c", md, outputs, tmp_path,
                {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: str(venv), "LD_DEBUG": "files"})
    assert run.returncode == 2 and loaded_pythons(run.stderr) == set()
    (message,) = [line for line in run.stderr.splitlines() if line.startswith("[")]
    assert (f"{OVERRIDE_VARIABLE} = {venv}: a virtual environment of CPython 3.10 (its pyvenv.cfg), whose "
            "installation has no CPython 3.10 library (looked for lib/libpython3.X.so.1.0 or "
            "lib/x86_64-linux-gnu/libpython3.X.so.1.0 in its home and the home's parent)") in message, message


def test_an_fmu_under_a_non_ascii_path_runs_in_a_host_with_the_c_locale(importer, fmu_paths, tmp_path):
    """The CPython started here is in UTF-8 mode: from an empty environment (the C locale, whose encoding is
    ASCII), DSCController unzipped under "Röbot 模型" gives the rows it gives under an ASCII path."""
    md, outputs = controller(fmu_paths, tmp_path / "ascii")
    unicode = tmp_path / "Röbot 模型"
    controller(fmu_paths, unicode)
    expected = c_run(importer, 2, tmp_path / "ascii", md, outputs, tmp_path)
    run = c_run(importer, 2, unicode, md, outputs, tmp_path)
    assert expected.returncode == 0 and run.returncode == 0, run.stderr[-2000:]
    assert parse_rows(run.stdout) == parse_rows(expected.stdout)


def test_a_cpython_that_failed_before_starting_leaves_nothing_behind(importer, fmu_paths, tmp_path):
    """The override names a folder holding a copy of CPython 3.12's library without its standard library
    (tried first: the FMU prefers 3.10, absent, then the newest) and the building CPython 3.11, which starts.
    The FMU's bridge module raises on import: that exception, taken through 3.11's API (not the unloaded
    3.12's newer one), is the one message, and the importer is told in a NULL instance."""
    built = build_python()
    assert built.version == "3.11", "the building CPython must be older than 3.12 for this test"
    md, outputs = controller(fmu_paths, tmp_path / "c")
    folder = tmp_path / "c"
    runtime = PythonRuntime("3.10", "/nonexistent/lib/libpython3.10.so.1.0", "/nonexistent")
    (folder / LINUX.file(2, "DSCController")).write_bytes(compile_binary(2, LINUX, runtime))
    bridge = (folder / "resources" / ENTRY_FILE).read_text().split()[0]
    (folder / "resources" / (bridge.replace(".", "/") + ".py")).write_text("raise RuntimeError('broken on purpose')\n")
    pythons = tmp_path / "pythons" / "lib"
    pythons.mkdir(parents=True)
    shutil.copy(shared_cpython(12), pythons / "libpython3.12.so.1.0")
    (pythons / "libpython3.11.so.1.0").symlink_to(built.library)
    run = c_run(importer, 2, folder, md, outputs, tmp_path,
                {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: str(pythons.parent)})
    assert run.returncode == 2, run.stderr[-2000:]
    (message,) = [line for line in run.stderr.splitlines() if line.startswith("[")]
    assert "importing the FMU's package failed: RuntimeError: broken on purpose" in message, message
