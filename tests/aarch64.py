"""aarch64 Linux for the tests, under Debian's qemu-user: an arm64 Debian root made by ``mmdebstrap`` from
Debian's packages, with the project's runtime dependencies put into it by the host's pip. Made once per
package list and kept in the user's cache (one process builds it, under a file lock; the others wait and
take it). The program run inside it (``python3.11 aarch64.py TASK ...``) calls the same functions the
host calls, so the two sides differ in the machine only. Without a tool the tests skip, except where
``DSC_FMU_CI`` is set (``wine.required``)."""

import json
import os
import sys
from pathlib import Path

import numpy as np

SUITE = "bookworm"
PYTHON = "3.11"
DEBIAN_PACKAGES = (f"python{PYTHON}", f"libpython{PYTHON}", "libstdc++6")
# What importing dsc_fmu's master and model exchange and fmpy's simulate_fmu needs (fmpy's other
# requirements serve its GUI, remoting and code generation), pinned to the host's versions.
PYTHON_PACKAGES = ("numpy", "scipy", "fmpy", "attrs", "lxml")
WHEEL_PLATFORMS = ("manylinux_2_28_aarch64", "manylinux2014_aarch64")
ZIG_TARGET = "aarch64-linux-gnu.2.17"
QEMU_REGISTRATION = Path("/usr/lib/binfmt.d/qemu-aarch64.conf")
BINFMT = Path("/proc/sys/fs/binfmt_misc")
ENVIRONMENT = {"PATH": "/usr/bin:/bin"}
SITE = "opt/site"
NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
PAPER_STOP = 2.0
EXCHANGE_STOP, EXCHANGE_TOLERANCE = 0.5, 1e-6


class Arm64Root:
    """An arm64 Debian root; its programs run under ``chroot`` with only PATH (and PYTHONPATH) set."""

    def __init__(self, path: Path):
        self.path = path

    def inside(self, path: Path) -> str:
        """``path`` (under the root) as the root's programs see it."""
        return "/" + str(Path(path).relative_to(self.path))

    def run(self, command: list, env: dict | None = None, timeout: float = 600):
        """Run ``command`` (paths as the root sees them) in the root from an empty environment."""
        import shutil
        import subprocess

        chroot = shutil.which("chroot", path="/usr/sbin:/usr/bin:/sbin:/bin")
        return subprocess.run([chroot, str(self.path), *(str(c) for c in command)], env={**ENVIRONMENT, **(env or {})},
                              capture_output=True, text=True, timeout=timeout)

    def workspace(self) -> Path:
        """A new folder of the caller's own in the root, with the project's sources and this file in it."""
        import shutil
        import tempfile

        import dsc_fmu
        from dsc_fmu.scenario import SCENARIO_DIR

        (self.path / "work").mkdir(exist_ok=True)
        folder = Path(tempfile.mkdtemp(prefix="test-", dir=self.path / "work"))
        ignore = shutil.ignore_patterns("__pycache__")
        shutil.copytree(Path(dsc_fmu.__file__).parent, folder / "src" / "dsc_fmu", ignore=ignore)
        shutil.copytree(SCENARIO_DIR, folder / "src" / "scenarios", ignore=ignore)
        shutil.copy(__file__, folder / "aarch64.py")
        return folder

    def run_task(self, folder: Path, task: str, fmus: dict, *options: str):
        """Run ``task`` of this file's ``TASKS`` in the root on ``fmus`` (files under ``folder``); its
        outputs as ``read_outputs`` gives them."""
        out = folder / f"{task}-out"
        out.mkdir()
        fmu_paths = json.dumps({name: self.inside(path) for name, path in fmus.items()})
        path = ":".join(self.inside(p) for p in (self.path / SITE, folder / "src", folder))
        run = self.run(["/usr/bin/python" + PYTHON, self.inside(folder / "aarch64.py"), task, fmu_paths,
                        self.inside(out), *options], env={"PYTHONPATH": path})
        assert run.returncode == 0, run.stderr[-3000:]
        return read_outputs(out)


def compile_for_aarch64(source: str, output: Path) -> Path:
    """Compile ``tests/<source>`` for aarch64 Linux (glibc 2.17), as ``c_hosts.compile_c`` does for x86-64."""
    import subprocess

    import fmpy

    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", ZIG_TARGET, "-O2", "-std=gnu11", f"-I{headers}",
                    "-o", str(output), str(Path(__file__).parent / source), "-D_GNU_SOURCE", "-ldl", "-lpthread"],
                   check=True, capture_output=True, timeout=600)
    return output


def elf_machine(data: bytes) -> int:
    """An ELF file's ``e_machine`` (62 x86-64, 183 aarch64)."""
    assert data[:4] == b"\x7fELF", data[:4]
    return int.from_bytes(data[18:20], "little")


def debian_mirror(apt: Path = Path("/etc/apt")) -> str:
    """The first mirror of ``SUITE`` in the host's apt sources (deb822 ``*.sources`` or one-line ``*.list``)."""
    for path in sorted(apt.glob("sources.list.d/*.sources")):
        for stanza in path.read_text().split("\n\n"):
            fields = {}
            for line in stanza.splitlines():
                key, _, value = line.partition(":")
                if line[:1] not in ("", "#", " ") and value:
                    fields[key.strip()] = value.split()
            if "deb" in fields.get("Types", []) and SUITE in fields.get("Suites", []) and fields.get("URIs"):
                return fields["URIs"][0]
    for path in [apt / "sources.list", *sorted(apt.glob("sources.list.d/*.list"))]:
        for line in path.read_text().splitlines() if path.is_file() else []:
            words = [w for w in line.split("#")[0].split() if not w.startswith("[")]
            if len(words) >= 3 and words[0] == "deb" and words[2] == SUITE:
                return words[1]
    return ""


def _specification() -> dict:
    """What the root is made of: its key in the cache."""
    from importlib.metadata import version

    return {"suite": SUITE, "debian": list(DEBIAN_PACKAGES), "wheels": list(WHEEL_PLATFORMS),
            "python": [f"{name}=={version(name)}" for name in PYTHON_PACKAGES]}


def _register_qemu() -> None:
    """binfmt_misc mounted and qemu-aarch64 registered (Debian's registration, whose F flag lets a chroot
    use the interpreter), as root."""
    import subprocess

    from wine import required

    if not (BINFMT / "register").exists():
        mount = subprocess.run(["mount", "-t", "binfmt_misc", "binfmt_misc", str(BINFMT)], capture_output=True,
                               text=True)
        if mount.returncode != 0:
            required(f"binfmt_misc cannot be mounted: {mount.stderr.strip()}")
    entry = BINFMT / "qemu-aarch64"
    if not entry.exists():
        (BINFMT / "register").write_text(QEMU_REGISTRATION.read_text().strip() + "\n")
    lines = entry.read_text().splitlines()
    if lines[0] != "enabled":
        entry.write_text("1")
    flags = next(line.split()[1] for line in lines if line.startswith("flags:"))
    if "F" not in flags:
        required(f"qemu-aarch64 is registered without the F flag ({flags}): a chroot cannot reach the interpreter")


def _build(folder: Path, specification: dict) -> None:
    """Make the root in ``folder`` (new): mmdebstrap, then the host's pip."""
    import subprocess

    from wine import required

    mirror = debian_mirror()
    if not mirror:
        required(f"no Debian mirror of {SUITE} in the host's apt sources")
    root = folder / "root"
    debootstrap = subprocess.run(["mmdebstrap", "--arch=arm64", "--variant=extract",
                                  "--include=" + ",".join(DEBIAN_PACKAGES), SUITE, str(root), mirror],
                                 capture_output=True, text=True, timeout=900)
    assert debootstrap.returncode == 0, debootstrap.stderr[-3000:]
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                          "--no-deps", "--only-binary=:all:", "--target", str(root / SITE),
                          *(f"--platform={p}" for p in WHEEL_PLATFORMS), "--python-version", PYTHON,
                          "--implementation", "cp", *specification["python"]],
                         capture_output=True, text=True, timeout=900,
                         env={**os.environ, "PIP_ROOT_USER_ACTION": "ignore"})
    assert pip.returncode == 0, pip.stderr[-3000:]
    (folder / "specification.json").write_text(json.dumps(specification))


def _intact(folder: Path, specification: dict) -> bool:
    marker = folder / "specification.json"
    return (marker.is_file() and json.loads(marker.read_text()) == specification
            and (folder / "root" / "usr" / "bin" / f"python{PYTHON}").is_file()
            and (folder / "root" / SITE / "fmpy").is_dir())


def debian_root() -> Arm64Root:
    """The arm64 Debian root of ``_specification()``: taken from the cache, or made there (as root: mmdebstrap,
    Debian's qemu-user-static, chroot)."""
    import fcntl
    import hashlib
    import shutil

    from dsc_fmu.fmubuild.bundle.windows import cache_folder
    from wine import required

    if os.geteuid() != 0:
        required("the aarch64 root needs root (mount, chroot)")
    for tool in ("mmdebstrap", "chroot"):
        if not shutil.which(tool, path="/usr/sbin:/usr/bin:/sbin:/bin"):
            required(f"{tool} is not installed (Debian: apt-get install mmdebstrap qemu-user-static)")
    if not QEMU_REGISTRATION.is_file():
        required("qemu-user-static is not installed (Debian: apt-get install qemu-user-static)")
    specification = _specification()
    key = hashlib.sha256(json.dumps(specification, sort_keys=True).encode()).hexdigest()[:16]
    cache = cache_folder() / "aarch64"
    cache.mkdir(parents=True, exist_ok=True)
    folder = cache / key
    with open(cache / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        _register_qemu()
        if not _intact(folder, specification):
            partial = cache / f".{key}.{os.getpid()}"
            shutil.rmtree(partial, ignore_errors=True)
            partial.mkdir()
            try:
                _build(partial, specification)
                shutil.rmtree(folder, ignore_errors=True)
                partial.rename(folder)
            finally:
                shutil.rmtree(partial, ignore_errors=True)
    return Arm64Root(folder / "root")


def fmu_outputs(fmus: dict) -> set[str]:
    """The names of the outputs of ``fmus``."""
    from fmpy import read_model_description

    return {v.name for path in fmus.values() for v in read_model_description(str(path)).modelVariables
            if v.causality == "output"}


def read_outputs(folder: Path) -> dict:
    """What a task wrote: its arrays by name, and its other values."""
    outputs = json.loads((folder / "values.json").read_text())
    outputs.update({path.stem: np.load(path) for path in folder.glob("*.npy")})
    return outputs


def paper_cosimulation(fmus: dict) -> dict:
    """The paper's scenario for ``PAPER_STOP`` s through ``dsc_fmu.cosimulate``."""
    from dsc_fmu import cosimulate, load_scenario

    run = cosimulate(load_scenario("paper").with_simulation(stop_time=PAPER_STOP), fmus)
    return {"result": run.result, "steps": run.steps}


def paper_model_exchange(fmus: dict) -> dict:
    """The paper's scenario for ``EXCHANGE_STOP`` s through ``dsc_fmu.simulate_model_exchange``."""
    from dsc_fmu import load_scenario, simulate_model_exchange

    run = simulate_model_exchange(load_scenario("paper"), fmus, stop_time=EXCHANGE_STOP, tolerance=EXCHANGE_TOLERANCE)
    return {"result": run.result, "steps": run.steps}


def fmpy_user(fmus: dict, library_folder: str = "") -> dict:
    """``fmpy.simulate_fmu(path)`` for each FMU as a user of fmpy calls it (its result, or the exception's
    type and message), and with ``library_folder`` the same through an ``FMU2Slave`` of the binary in
    ``binaries/<library_folder>`` (``fmu_instance``); fmpy's platform names."""
    import shutil

    import fmpy
    from fmpy.fmi2 import FMU2Slave

    outputs = {"platform": [fmpy.platform, fmpy.platform_tuple]}
    for name, path in fmus.items():
        try:
            outputs[name] = fmpy.simulate_fmu(str(path))
        except Exception as error:
            outputs[name] = {"type": type(error).__name__, "message": str(error)}
        if library_folder:
            description = fmpy.read_model_description(str(path))
            unzipped = fmpy.extract(str(path))
            identifier = description.coSimulation.modelIdentifier
            library = os.path.join(unzipped, "binaries", library_folder, identifier + fmpy.sharedLibraryExtension)
            instance = FMU2Slave(guid=description.guid, unzipDirectory=unzipped, modelIdentifier=identifier,
                                 libraryPath=library)
            instance.instantiate()
            try:
                outputs[f"{name}-instance"] = fmpy.simulate_fmu(unzipped, fmu_instance=instance)
            finally:
                instance.freeInstance()
                shutil.rmtree(unzipped)
    return outputs


def bundled_runtime(fmus: dict) -> dict:
    """What ``--bundle-python`` carries when built here for the one FMU of ``fmus``: this platform, the
    platforms an FMU built here can carry a CPython for, the runtimes made for this platform, and the ELF
    machine of each library of this platform's runtime."""
    import zipfile

    from dsc_fmu.fmubuild.binary import TARGETS, ENTRY_FILE, host_target
    from dsc_fmu.fmubuild.bundle import bundled_runtimes, carried_platforms

    (path,) = fmus.values()
    with zipfile.ZipFile(path) as fmu:
        entry = " ".join(fmu.read(f"resources/{ENTRY_FILE}").decode().split()[:2])
    here = host_target().name
    runtimes = bundled_runtimes(Path(path), entry, True, [target.name for target in TARGETS if target.os == "linux"])
    runtime = runtimes[here]
    return {"host": here, "carried": carried_platforms([target.name for target in TARGETS]),
            "platforms": sorted(runtimes), "os": runtime.os, "needs": list(runtime.needs), "licences": sorted(runtime.licences),
            "machines": {name: elf_machine(data) for name, data in runtime.files.items() if ".so" in name}}


def ssp_in_fmpy(fmus: dict) -> dict:
    """``run_simulate_ssp`` of the SSP archive that is the one file of ``fmus``: the error it raises."""
    from dsc_fmu.interop.ssp import SSPError, run_simulate_ssp

    (archive,) = fmus.values()
    try:
        run_simulate_ssp(archive, 1e-3, 0.01)
    except SSPError as error:
        return {"error": str(error)}
    return {"error": None}


TASKS = {"cosimulation": paper_cosimulation, "model-exchange": paper_model_exchange, "fmpy": fmpy_user,
         "bundle": bundled_runtime, "ssp": ssp_in_fmpy}


def main(task: str, fmus: str, out: str, *options: str) -> None:
    """Run ``TASKS[task]`` on the FMUs (a JSON object of paths by name) and write its arrays as ``.npy``
    and its other values to ``values.json`` in ``out``."""
    outputs = TASKS[task](json.loads(fmus), *options)
    values = {}
    for key, value in outputs.items():
        if isinstance(value, np.ndarray):
            np.save(Path(out) / f"{key}.npy", value)
        else:
            values[key] = value
    (Path(out) / "values.json").write_text(json.dumps(values))


if __name__ == "__main__":
    main(*sys.argv[1:])
