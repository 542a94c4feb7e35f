"""The binary layer in hosts that do what real tools do: a logger that blocks, thread pools, threads with
small stacks, a Python that cannot start, a wrong token, FMUs whose bundled pythonfmu differ, a host with
a pythonfmu of its own, hosts that free the FMUs and delete their folders, and hosts whose standard
streams are files or closed. C hosts run with an empty environment."""

import json
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
import pythonfmu
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

import dsc_fmu.fmubuild.fmus as fmus_module
from c_hosts import EMPTY_ENVIRONMENT, compile_c, parse_rows, run_c
from test_c_importer import importer  # noqa: F401 (fixture)
from dsc_fmu.fmubuild.binary import OVERRIDE_VARIABLE, build_python
from dsc_fmu.fmubuild.fmus import build_fmu
from dsc_fmu.registry import FMUS

STEPS = 200
THREADS = 2000


@pytest.fixture(scope="module")
def c_threads(tmp_path_factory):
    return compile_c("c_threads.c", tmp_path_factory.mktemp("c") / "c_threads")


def unzipped(path: Path, folder: Path):
    md = read_model_description(str(path))
    token = md.guid if md.fmiVersion.startswith("2") else md.instantiationToken
    return Path(extract(str(path), unzipdir=folder)), md, token


def fields(line: str) -> dict:
    return {key: value for key, _, value in (item.partition("=") for item in line.split())}


@pytest.mark.parametrize("version", (2, 3))
def test_a_blocking_logger_never_holds_up_another_instance(c_threads, fmu_paths, fmu3_paths, tmp_path, version):
    """Instance A's logger waits until instance B, on another thread, has done its steps: B steps
    while A's logger waits (with the GIL held by A's logger, B could not, and A would time out)."""
    path = (fmu3_paths if version == 3 else fmu_paths)["MobileRobot"]
    folder, md, token = unzipped(path, tmp_path / "plant")
    mass = {v.name: v.valueReference for v in md.modelVariables}["mc"]
    run = run_c([c_threads, "logger", version, folder, "MobileRobot", token, mass, -1.0, STEPS], tmp_path)
    assert run.returncode == 0, run.stderr
    result = fields(run.stdout)
    assert result == {"steps_while_logger_waited": str(STEPS), "logger_calls": "1", "timed_out": "0"}, run.stdout


@pytest.mark.parametrize("version", (2, 3))
def test_short_lived_threads_leave_no_thread_state_behind(c_threads, fmu_paths, fmu3_paths, tmp_path, version):
    """2,000 threads, one after another, each stepping one instance once: no Python thread state
    outlives its thread, and the process grows by less than 1 MB."""
    path = (fmu3_paths if version == 3 else fmu_paths)["ReferenceRobot"]
    folder, md, token = unzipped(path, tmp_path / "reference")
    run = run_c([c_threads, "threads", version, folder, "ReferenceRobot", token, THREADS], tmp_path)
    assert run.returncode == 0, run.stderr
    result = fields(run.stdout)
    before, after = (int(kb) for kb in result["rss_kb"].split(","))
    states = [int(n) for n in result["thread_states"].split(",")]
    assert states[1] == states[0], run.stdout
    assert after - before < 1024, run.stdout


@pytest.mark.parametrize("version", (2, 3))
def test_a_host_may_join_its_threads_holding_the_gil(c_threads, fmu_paths, fmu3_paths, tmp_path, version):
    """A worker thread that stepped an instance ends while this thread holds the GIL and joins it (as a
    Python extension's destructor may): its thread state is deleted later, by the FMU's reaper."""
    folder, md, token = unzipped((fmu3_paths if version == 3 else fmu_paths)["ReferenceRobot"], tmp_path / "r")
    run = run_c([c_threads, "join", version, folder, "ReferenceRobot", token], tmp_path, timeout=60)
    assert run.returncode == 0 and fields(run.stdout) == {"joined": "1"}, run.stdout + run.stderr


@pytest.mark.parametrize("version", (2, 3))
def test_threads_create_and_free_instances_of_one_build_at_once(c_threads, fmu_paths, fmu3_paths, tmp_path, version):
    """8 threads, each creating, stepping and freeing an instance 25 times, all at once: the build's
    modules are imported, counted and forgotten whole."""
    folder, md, token = unzipped((fmu3_paths if version == 3 else fmu_paths)["MobileRobot"], tmp_path / "plant")
    run = run_c([c_threads, "create", version, folder, "MobileRobot", token, 8, 25], tmp_path)
    assert run.returncode == 0 and fields(run.stdout) == {"failures": "0"}, run.stdout + run.stderr


SMALL_STACK_KB = 64


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", FMUS)
def test_an_instance_lives_its_whole_life_on_a_thread_with_a_64_kb_stack(c_threads, fmu_paths, fmu3_paths, tmp_path,
                                                                         name, version):
    """Hosts call FMUs from worker threads with small stacks. In a process that has not called the FMU before
    (so that its first call, which finds and starts CPython, is made there too), an instance is created,
    initialised, stepped, terminated and freed on a thread with a 64 kB stack, and its outputs are those of
    the same run on the main thread, row for row and bit for bit."""
    folder, md, token = unzipped((fmu3_paths if version == 3 else fmu_paths)[name], tmp_path / name)
    refs = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Float64")]
    runs = {kb: run_c([c_threads, "stack", version, folder, name, token, kb, STEPS, *refs], tmp_path)
            for kb in (0, SMALL_STACK_KB)}
    for kb, run in runs.items():
        assert run.returncode == 0, f"stack {kb or 'main thread'} kB: exit {run.returncode}: {run.stderr[-2000:]}"
    assert len(parse_rows(runs[0].stdout)) == STEPS + 1
    assert runs[SMALL_STACK_KB].stdout == runs[0].stdout


@pytest.fixture()
def broken_python(tmp_path):
    """A libpython whose standard library cannot start: encodings raises on import."""
    built = build_python()
    if not built.library:
        pytest.fail("the Python running the tests has no shared library to copy")
    home = tmp_path / "broken-python"
    stdlib = home / "lib" / f"python{built.version}"
    (stdlib / "encodings").mkdir(parents=True)
    shutil.copy(Path(sysconfig.get_paths()["stdlib"]) / "os.py", stdlib / "os.py")
    (stdlib / "encodings" / "__init__.py").write_text('raise ImportError("this standard library is broken")\n')
    library = home / "lib" / Path(built.library).name
    shutil.copy(built.library, library)
    return library


@pytest.mark.parametrize("version", (2, 3))
def test_a_python_that_cannot_start_is_a_null_instance_and_one_message(importer, fmu_paths, fmu3_paths, tmp_path,
                                                                       broken_python, version):
    path = (fmu3_paths if version == 3 else fmu_paths)["ReferenceRobot"]
    folder, md, token = unzipped(path, tmp_path / "reference")
    env = {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: str(broken_python)}
    run = run_c([importer, version, folder, "ReferenceRobot", token, 1, 0.1, 10], tmp_path, env)
    assert run.returncode == 2, run.stderr  # the host lived on to report the NULL
    messages = [line for line in run.stderr.splitlines() if line.startswith("[")]
    assert len(messages) == 1, run.stderr
    assert str(broken_python) in messages[0] and "Python did not start: init_fs_encoding" in messages[0]


@pytest.mark.parametrize("version", (2, 3))
def test_the_token_is_checked_before_any_python_is_looked_for(importer, fmu_paths, fmu3_paths, tmp_path, version):
    """With no Python to be found, a wrong token is still what the host is told."""
    path = (fmu3_paths if version == 3 else fmu_paths)["ReferenceRobot"]
    folder, md, token = unzipped(path, tmp_path / "reference")
    env = {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: "/nonexistent/libpython.so"}
    run = run_c([importer, version, folder, "ReferenceRobot", "{not-the-guid}", 1, 0.1, 10], tmp_path, env)
    assert run.returncode == 2, run.stderr
    messages = [line for line in run.stderr.splitlines() if line.startswith("[")]
    assert len(messages) == 1 and "the token {not-the-guid} does not match" in messages[0], run.stderr


SHIFT = 1000.0


@pytest.fixture(scope="module")
def variant(tmp_path_factory):
    """ReferenceRobot built as with another pythonfmu (a build identity of its own), whose bundled
    pythonfmu returns every Real 1000 higher: what runs shows which pythonfmu ran. Built without the traced C
    (``--no-traced``), so that every value is read through pythonfmu."""
    folder = tmp_path_factory.mktemp("variant")
    patch = pytest.MonkeyPatch()
    patch.setattr(fmus_module, "_library_version", lambda version: f"pythonfmu {pythonfmu.__version__}+variant")
    try:
        built = build_fmu(FMUS["ReferenceRobot"], folder / "built", traced=False)
    finally:
        patch.undo()
    path = folder / "ReferenceRobot.fmu"
    with zipfile.ZipFile(built) as source, zipfile.ZipFile(path, "w") as target:
        for item in source.infolist():
            data = source.read(item)
            if item.filename.endswith("/pythonfmu/fmi2slave.py"):
                original = b"refs.append(float(var.getter()))"
                assert original in data
                data = data.replace(original, b"refs.append(float(var.getter()) + %r)" % SHIFT)
            target.writestr(item, data)
    return path


def test_two_builds_with_different_pythonfmu_each_run_their_own_in_a_c_host(importer, fmu_paths, variant, tmp_path):
    folders, tokens = [], []
    for name, path in (("original", fmu_paths["ReferenceRobot"]), ("variant", variant)):
        folder, md, token = unzipped(path, tmp_path / name)
        folders.append(str(folder))
        tokens.append(token)
    refs = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    run = run_c([importer, 2, ",".join(folders), "ReferenceRobot", ",".join(tokens), 5, 0.1, *refs], tmp_path)
    assert run.returncode == 0, run.stderr
    for row in parse_rows(run.stdout):
        original, shifted = row[1:1 + len(refs)], row[1 + len(refs):]
        assert shifted == [value + SHIFT for value in original]


def _outputs(path: Path, folder: Path) -> list[float]:
    md = read_model_description(str(path))
    refs = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(extract(str(path), unzipdir=folder)),
                    modelIdentifier="ReferenceRobot", instanceName=folder.name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.doStep(0.0, 0.1)
    values = fmu.getReal(refs)
    fmu.terminate()
    fmu.freeInstance()
    return values


def test_in_a_python_host_with_its_own_pythonfmu_nothing_is_shared_and_nothing_is_left(fmu_paths, variant, tmp_path):
    """fmpy in this process, where pythonfmu is imported: each FMU runs its own bundled pythonfmu, the
    host's pythonfmu stays the host's, and once the FMUs are freed and their folders deleted, the
    host's sys.path and sys.modules are as they were."""
    host_pythonfmu = sys.modules["pythonfmu"]
    path_before, modules_before = list(sys.path), set(sys.modules)
    original = _outputs(fmu_paths["ReferenceRobot"], tmp_path / "original")
    shifted = _outputs(variant, tmp_path / "variant")
    assert shifted == [value + SHIFT for value in original]
    for folder in ("original", "variant"):
        shutil.rmtree(tmp_path / folder)
    assert sys.modules["pythonfmu"] is host_pythonfmu
    assert sys.path == path_before
    assert set(sys.modules) - modules_before == set()
    assert not any(str(tmp_path) in str(key) for key in sys.path_importer_cache)


def test_one_build_extracted_twice_is_forgotten_in_both_folders(fmu_paths, tmp_path):
    """Two instances of one build from two folders share its modules (one count); once both are freed,
    nothing of either folder is left in the import system."""
    path = fmu_paths["MobileRobot"]
    md = read_model_description(str(path))
    modules_before = set(sys.modules)
    instances = []
    for folder in ("first", "second"):
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(extract(str(path), unzipdir=tmp_path / folder)),
                        modelIdentifier="MobileRobot", instanceName=folder)
        fmu.instantiate()
        instances.append(fmu)
    instances[0].freeInstance()
    assert any(name.startswith("dsc_fmu_mobilerobot_") for name in sys.modules)  # the second still uses them
    instances[1].freeInstance()
    assert set(sys.modules) - modules_before == set()
    assert not any(str(tmp_path) in str(key) for key in sys.path_importer_cache)


@pytest.mark.parametrize("streams", ("file", "closed"))
def test_hosts_whose_standard_streams_are_files_or_absent(importer, fmu_paths, tmp_path, streams):
    """A C host whose standard output is a regular file gets the rows a pipe gets; one started with
    standard input, output and error closed (a daemon, a GUI tool) runs every call successfully."""
    folder, md, token = unzipped(fmu_paths["DSCController"], tmp_path / "c")
    refs = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    command = [str(c) for c in (importer, 2, folder, "DSCController", token, 20, 0.01, *refs)]
    piped = run_c(command, tmp_path)
    assert piped.returncode == 0, piped.stderr
    output = tmp_path / "stdout.txt"
    with open(output, "w") as target:
        if streams == "file":
            run = subprocess.run(command, cwd=tmp_path, env=EMPTY_ENVIRONMENT, stdout=target, stderr=subprocess.PIPE,
                                 text=True, timeout=120)
        else:
            run = subprocess.run(command, cwd=tmp_path, env=EMPTY_ENVIRONMENT, stdin=subprocess.DEVNULL,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=120,
                                 preexec_fn=lambda: [os.close(fd) for fd in (0, 1, 2)])
    assert run.returncode == 0
    if streams == "file":
        assert parse_rows(output.read_text()) == parse_rows(piped.stdout)


FORK_AFTER_UNLOAD = r"""
import os, sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
md = read_model_description(sys.argv[1])
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]), modelIdentifier="ReferenceRobot")
fmu.instantiate()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
fmu.doStep(0.0, 0.01)
fmu.terminate()
fmu.freeInstance()
fmu.freeLibrary()
child = os.fork()
if child == 0:
    os._exit(7)
print("child exit", os.waitstatus_to_exitcode(os.waitpid(child, 0)[1]))
"""


def test_a_host_may_fork_after_unloading_an_fmu(fmu_paths, tmp_path):
    """fmpy frees an FMU and unloads its binary (dlclose), then the process forks (multiprocessing's
    fork, a subprocess with preexec_fn): the binary left no fork handler behind to call into."""
    run = subprocess.run([sys.executable, "-c", FORK_AFTER_UNLOAD, str(fmu_paths["ReferenceRobot"])], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "child exit 7", run.stderr[-2000:]


def default_interrupt() -> None:
    """In the host's process before its Python starts: SIGINT as a terminal's program gets it, even where the tests
    run with it ignored (started in the background by a shell without job control; the ignoring is inherited), so
    that its Python turns it into KeyboardInterrupt."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


INTERRUPTED_HOST = r"""
import json, sys
from dsc_fmu.cosim.master import Cosimulator, CosimulationError
from dsc_fmu.scenario import load_scenario
paths = json.loads(sys.argv[1])
with Cosimulator(paths) as simulator:
    try:
        simulator.run(load_scenario("paper"), stop_time=0.2)
        print("finished")
    except KeyboardInterrupt:
        print("KeyboardInterrupt")
    except CosimulationError as error:
        print("CosimulationError", error)
    print(json.dumps([m.message for m in simulator.log]))
"""


def test_a_ctrl_c_inside_the_model_code_reaches_the_host_as_its_own(patched_mobile_robot, fmu_paths, tmp_path):
    """Ctrl-C while the model code runs in the host's Python (here the step raises KeyboardInterrupt, as
    Python does where SIGINT finds it): the FMI call fails and the FMU logs that it was interrupted,
    not that the model failed, and the host's Python gets the KeyboardInterrupt once the call
    returns, not a failure of the FMU."""
    interrupting = patched_mobile_robot(
        '    """A ``MobileRobotModel`` in the FMI 2.0 slave (pythonfmu)."""\n',
        "\n    def do_step(self, current_time, step_size):\n        if current_time >= 0.05:\n"
        "            raise KeyboardInterrupt\n        return super().do_step(current_time, step_size)\n",
        "interrupting")
    paths = {**{name: str(path) for name, path in fmu_paths.items()}, "MobileRobot": str(interrupting)}
    run = subprocess.run([sys.executable, "-c", INTERRUPTED_HOST, json.dumps(paths)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    outcome, log = run.stdout.splitlines()
    assert outcome == "KeyboardInterrupt"
    assert any("do_step interrupted: the KeyboardInterrupt goes on to the host" in m for m in json.loads(log))
    assert not any("failed" in m for m in json.loads(log))
