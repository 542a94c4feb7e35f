"""Instances freed while the host's CPython shuts down: Python hosts that keep an FMU in a module global to
the very end and free it from a deallocator (as PyFMI's Cython objects do: terminate, then free), through
fmpy and through ctypes alone (in CPython 3.9, 3.11, 3.12, 3.13); and a C host that embeds CPython and frees them once
it has finalized. The binary then releases C memory only: nothing is logged as an error and the process
exits 0."""

import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from c_hosts import EMPTY_ENVIRONMENT, compile_c, run_c
from test_c_importer import OTHER_MINORS, cpython_home, shared_cpython
from test_real_hosts import unzipped
from wine import required

HERE = Path(__file__).parent
MINORS = sorted({*OTHER_MINORS, sys.version_info.minor})  # the oldest CPython the FMUs take, this one, newer ones
ERROR = 3  # fmi2Error, fmi3Error; fatal is 4

# Shared by both hosts: a logger that writes each message at once (its line survives the host's end) and
# the holder, which terminates and frees its instances, and frees their FMU states, when it is
# deallocated: when module teardown clears the globals, after atexit has run.
HOLDER = r"""
import os, sys

def say(text, _write=os.write):
    _write(1, (text + "\n").encode("utf-8", "replace"))

def logged(status, message, _say=say):
    _say("LOG %d %s" % (status, message.decode("utf-8", "replace") if message else ""))

class Holder:
    def __init__(self, calls):
        self.calls = calls  # (terminate, free state, free instance, instance, FMU state) of each instance

    def __del__(self, _say=say):
        for terminate, free_state, free, instance, state in self.calls:
            _say("terminate %d" % terminate(instance))
            _say("free state %d" % free_state(instance, state))
            free(instance)
        _say("freed at shutdown")
"""

FMPY_HOST = HOLDER + r"""
import ctypes
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi2 import FMU2Model, FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
from fmpy.fmi3 import FMU3Model, FMU3Slave

path = sys.argv[1]
md = read_model_description(path)
version = int(md.fmiVersion[0])
folder = extract(path)
callbacks = fmi2CallbackFunctions()
callbacks.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, category, message: logged(status, message))
callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
calls, kept = [], []
for cls in ((FMU2Slave, FMU2Model) if version == 2 else (FMU3Slave, FMU3Model)):
    fmu = cls(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
              instanceName=cls.__name__)
    if version == 2:
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
        fmu.setupExperiment(startTime=0.0)
    else:
        fmu.instantiate(loggingOn=True, logMessage=lambda env, status, category, message: logged(status, message))
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    if cls in (FMU2Slave, FMU3Slave):
        fmu.doStep(0.0, 0.01)
    state = fmu.getFMUState() if version == 3 else fmu.getFMUstate()
    prefix = "fmi%d" % version
    calls.append((getattr(fmu, prefix + "Terminate"), getattr(fmu, prefix + ("FreeFMUState" if version == 3 else
                  "FreeFMUstate")), getattr(fmu, prefix + "FreeInstance"), fmu.component, ctypes.byref(state)))
    kept.append((fmu, state))
holder = Holder(calls)
say("held to the end")
"""

CTYPES_HOST = HOLDER + r"""
import ctypes, importlib.util

spec = importlib.util.spec_from_file_location("fmi_ctypes", sys.argv[1])
fmi_ctypes = importlib.util.module_from_spec(spec)
spec.loader.exec_module(fmi_ctypes)
fmi_ctypes.Fmi2Slave._log = lambda self, env, name, status, category, message: logged(status, message)
fmi_ctypes.Fmi3Slave._log = lambda self, env, status, category, message: logged(status, message)
version, folder = int(sys.argv[2]), sys.argv[3]
calls, kept = [], []
for model_exchange in (False, True):
    slave = (fmi_ctypes.Fmi2Slave if version == 2 else fmi_ctypes.Fmi3Slave)(folder, "ME" if model_exchange else "CS")
    slave.instantiate(model_exchange=model_exchange)
    if version == 2:
        slave.setup_experiment()
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    if not model_exchange:
        slave.do_step(0.0, 0.01)
    prefix, dll = "fmi%d" % version, slave.dll
    state = ctypes.c_void_p()
    get_state = getattr(dll, prefix + ("GetFMUState" if version == 3 else "GetFMUstate"))
    get_state.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)]
    free_state = getattr(dll, prefix + ("FreeFMUState" if version == 3 else "FreeFMUstate"))
    free_state.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)]
    assert get_state(slave.instance, ctypes.byref(state)) == 0
    terminate = getattr(dll, prefix + "Terminate")
    terminate.argtypes = [ctypes.c_void_p]
    free = getattr(dll, prefix + "FreeInstance")
    free.argtypes = [ctypes.c_void_p]
    calls.append((terminate, free_state, free, slave.instance, ctypes.byref(state)))
    kept.append((slave, state))
holder = Holder(calls)
say("the model code runs in this interpreter: %s" % any(name.startswith("dsc_fmu_") for name in sys.modules))
say("held to the end")
"""


def assert_freed_quietly(run: subprocess.CompletedProcess, instances: int) -> None:
    """The host ended normally after freeing ``instances`` instances at shutdown, and no message had a
    status of error or worse."""
    lines = run.stdout.splitlines()
    assert run.returncode == 0, run.stderr[-3000:]
    assert lines[-1] == "freed at shutdown", run.stdout[-3000:] + run.stderr[-3000:]
    assert lines.count("terminate 0") == instances and lines.count("free state 0") == instances, run.stdout
    statuses = [int(line.split()[1]) for line in lines if line.startswith("LOG ")]
    assert all(status < ERROR for status in statuses), run.stdout
    assert "import lock" not in run.stdout + run.stderr
    assert "Exception ignored" not in run.stderr, run.stderr


@pytest.mark.parametrize("version", (2, 3))
def test_fmpy_host_frees_at_interpreter_shutdown(fmu_paths, fmu3_paths, tmp_path, version):
    """fmpy in a script that keeps a co-simulation and a model-exchange instance of one FMU (and an FMU
    state of each) to the end, freed by a deallocator during interpreter shutdown."""
    path = (fmu3_paths if version == 3 else fmu_paths)["DSCController"]
    run = subprocess.run([sys.executable, "-c", FMPY_HOST, str(path)], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300)
    assert "held to the end" in run.stdout, run.stderr[-3000:]
    assert_freed_quietly(run, 2)


@pytest.mark.parametrize("minor", MINORS, ids=lambda minor: f"3.{minor}")
@pytest.mark.parametrize("version", (2, 3))
def test_ctypes_host_frees_at_interpreter_shutdown(fmu_paths, fmu3_paths, tmp_path, version, minor):
    """A host on ctypes alone (as FMI Library's C calls are to PyFMI), in each CPython the FMUs take (whose
    ``Py_IsFinalizing`` is public from 3.13, ``_Py_IsFinalizing`` before): a co-simulation and a
    model-exchange instance kept to the end, freed by a deallocator during interpreter shutdown. The
    binary uses the host's Python, whatever its minor version."""
    from fmpy import extract

    python = cpython_home(minor) / "bin" / f"python3.{minor}"
    python = Path(sys.executable) if minor == sys.version_info.minor else python
    if not python.is_file():
        required(f"no {python}")
    path = (fmu3_paths if version == 3 else fmu_paths)["ReferenceRobot"]
    folder = extract(str(path), unzipdir=tmp_path / "fmu")
    run = subprocess.run([str(python), "-I", "-c", CTYPES_HOST, str(HERE / "fmi_ctypes.py"), str(version), folder],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert "held to the end" in run.stdout, run.stderr[-3000:]
    assert "the model code runs in this interpreter: True" in run.stdout
    assert_freed_quietly(run, 2)


@pytest.fixture(scope="module")
def c_finalized(tmp_path_factory):
    return compile_c("c_finalized.c", tmp_path_factory.mktemp("c") / "c_finalized")


def embedded_cpython(minor: int) -> tuple[Path, Path]:
    """The shared library and home of CPython 3.``minor`` for a C host to embed: the one this suite runs on,
    or an installed one."""
    if minor != sys.version_info.minor:
        return shared_cpython(minor), cpython_home(minor)
    library = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("INSTSONAME")
    if not library.is_file():
        required(f"no shared CPython library {library} to embed")
    return library, Path(sys.base_prefix)


@pytest.mark.parametrize("when", ("after", "atexit"))
@pytest.mark.parametrize("minor", MINORS, ids=lambda minor: f"3.{minor}")
@pytest.mark.parametrize("version", (2, 3))
def test_a_c_host_frees_after_its_python_finalized(c_finalized, fmu_paths, fmu3_paths, tmp_path, version, minor,
                                                   when):
    """A C application that embeds CPython (each the FMUs take) terminates and frees a co-simulation and a
    model-exchange instance and frees their FMU states once that Python has finalized: after
    ``Py_FinalizeEx`` returned, or from a function ``Py_AtExit`` registered (Py_FinalizeEx calls it last).
    No crash, no message of error status."""
    library, home = embedded_cpython(minor)
    folder, _, token = unzipped((fmu3_paths if version == 3 else fmu_paths)["MobileRobot"], tmp_path / "fmu")
    run = run_c([c_finalized, library, version, folder, "MobileRobot", token, when], tmp_path,
                {**EMPTY_ENVIRONMENT, "PYTHONHOME": str(home)}, timeout=300)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert run.stdout.splitlines()[-1] == "freed"
    statuses = [int(line[1:line.index("]")].split()[-1]) for line in run.stderr.splitlines() if line.startswith("[")]
    assert all(status < ERROR for status in statuses), run.stderr
