"""Debian roots for the tests: made by ``mmdebstrap --variant=extract`` (Debian's packages unpacked, nothing
configured: seconds) with Python packages put into them by the host's pip, kept in the user's cache under a
key of what they are made of (one process builds a root, under a file lock; the others wait and take it);
their programs run under ``chroot`` from an empty environment. A task run inside (``python3.X debian_root.py
MODULE.FUNCTION FMUS OUT ...``) calls the same functions the host calls, so the two sides differ in the root
only. Used by ``aarch64.py`` (arm64 bookworm, under qemu-user) and ``test_new_cpythons.py`` (Debian
unstable's CPythons). Without a tool the tests skip, except where ``DSC_FMU_CI`` is set (``wine.required``)."""

import json
import os
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

ENVIRONMENT = {"PATH": "/usr/bin:/bin"}
SYSTEM_PATH = "/usr/sbin:/usr/bin:/sbin:/bin"
# The extract variant leaves out the merged-/usr links that newer suites ship no package for (their files
# are under /usr only): without them no program starts (its ELF interpreter is /lib64/...).
MERGED_USR = ("bin", "lib", "lib64", "sbin")
# A frozen mirror's unstable suite has a Release file past its Valid-Until.
APT_OPTIONS = ('Acquire::Check-Valid-Until "false"',)
PAPER_STOP = 2.0
EXCHANGE_STOP, EXCHANGE_TOLERANCE = 0.5, 1e-6


@dataclass(frozen=True)
class Site:
    """Python packages for the root's CPython ``python`` ("3.11"): wheels of ``requirements`` for ``platforms``,
    put into ``folder`` by the host's pip."""

    python: str
    platforms: tuple[str, ...]
    requirements: tuple[str, ...]

    @property
    def folder(self) -> str:
        return f"opt/site-{self.python}"


@dataclass(frozen=True)
class Specification:
    """What a root is made of, its key in the cache: a suite's ``packages`` for ``architecture`` (Debian's name;
    empty: the host's) and a ``Site`` for each of its CPythons; ``name`` names its folder in the cache."""

    name: str
    suite: str
    packages: tuple[str, ...]
    sites: tuple[Site, ...]
    architecture: str = ""

    def key(self) -> str:
        import hashlib

        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()[:16]


def host_versions(names, at_least=()) -> tuple[str, ...]:
    """Requirements of ``names``: the host's version of each, or for those in ``at_least`` that version or a
    newer one (a binary package may have wheels for a newer CPython only in later releases)."""
    from importlib.metadata import version

    return tuple(f"{name}{'>=' if name in at_least else '=='}{version(name)}" for name in names)


class DebianRoot:
    """A Debian root made from ``specification``; its programs run under ``chroot`` with only PATH (and what
    is given) set."""

    def __init__(self, path: Path, specification: Specification):
        self.path = path
        self.specification = specification

    def inside(self, path: Path) -> str:
        """``path`` (under the root) as the root's programs see it."""
        return "/" + str(Path(path).relative_to(self.path))

    def run(self, command: list, env: dict | None = None, timeout: float = 600):
        """Run ``command`` (paths as the root sees them) in the root from an empty environment."""
        import shutil
        import subprocess

        chroot = shutil.which("chroot", path=SYSTEM_PATH)
        return subprocess.run([chroot, str(self.path), *(str(c) for c in command)], env={**ENVIRONMENT, **(env or {})},
                              capture_output=True, text=True, timeout=timeout)

    def workspace(self, *modules: Path) -> Path:
        """A new folder of the caller's own in the root, with the project's sources, this file and ``modules``
        (the files of the tasks' modules) in it."""
        import shutil
        import tempfile

        import dsc_fmu
        from dsc_fmu.scenario import SCENARIO_DIR

        (self.path / "work").mkdir(exist_ok=True)
        folder = Path(tempfile.mkdtemp(prefix="test-", dir=self.path / "work"))
        ignore = shutil.ignore_patterns("__pycache__")
        shutil.copytree(Path(dsc_fmu.__file__).parent, folder / "src" / "dsc_fmu", ignore=ignore)
        shutil.copytree(SCENARIO_DIR, folder / "src" / "scenarios", ignore=ignore)
        for module in (__file__, *modules):
            shutil.copy(module, folder / Path(module).name)
        return folder

    def run_task(self, folder: Path, task, fmus: dict, *options: str, python: str = "") -> dict:
        """Run the function ``task`` (of this file or of a module given to ``workspace``) in the root's CPython
        ``python`` (default: its first site's) on ``fmus`` (files under ``folder``); its outputs as
        ``read_outputs`` gives them."""
        site = next(s for s in self.specification.sites if s.python == python or not python)
        import tempfile

        out = Path(tempfile.mkdtemp(prefix=f"{task.__name__}-out-", dir=folder))
        fmu_paths = json.dumps({name: self.inside(path) for name, path in fmus.items()})
        path = ":".join(self.inside(p) for p in (self.path / site.folder, folder / "src", folder))
        run = self.run([f"/usr/bin/python{site.python}", self.inside(folder / Path(__file__).name),
                        f"{task.__module__}.{task.__name__}", fmu_paths, self.inside(out), *options],
                       env={"PYTHONPATH": path})
        assert run.returncode == 0, run.stderr[-3000:]
        return read_outputs(out)


def host_suite() -> str:
    """The Debian suite this machine runs (``VERSION_CODENAME``), or ""."""
    import platform

    try:
        return platform.freedesktop_os_release().get("VERSION_CODENAME", "")
    except OSError:
        return ""


def debian_mirror(apt: Path = Path("/etc/apt"), suite: str = "bookworm") -> str:
    """The first mirror of ``suite`` in the host's apt sources (deb822 ``*.sources`` or one-line ``*.list``)."""
    for path in sorted(apt.glob("sources.list.d/*.sources")):
        for stanza in path.read_text().split("\n\n"):
            fields = {}
            for line in stanza.splitlines():
                key, _, value = line.partition(":")
                if line[:1] not in ("", "#", " ") and value:
                    fields[key.strip()] = value.split()
            if "deb" in fields.get("Types", []) and suite in fields.get("Suites", []) and fields.get("URIs"):
                return fields["URIs"][0]
    for path in [apt / "sources.list", *sorted(apt.glob("sources.list.d/*.list"))]:
        for line in path.read_text().splitlines() if path.is_file() else []:
            words = [w for w in line.split("#")[0].split() if not w.startswith("[")]
            if len(words) >= 3 and words[0] == "deb" and words[2] == suite:
                return words[1]
    return ""


def _build(folder: Path, specification: Specification) -> None:
    """Make the root in ``folder`` (new): mmdebstrap from the mirror of the host's own suite (a Debian mirror
    holds every suite), the merged-/usr links it leaves out, then the host's pip for each site."""
    import subprocess

    from wine import required

    mirror = debian_mirror(suite=host_suite())
    if not mirror:
        required(f"no Debian mirror of this machine's suite ({host_suite() or 'unknown'}) in its apt sources")
    root = folder / "root"
    debootstrap = subprocess.run(["mmdebstrap", "--variant=extract", *(f"--aptopt={o}" for o in APT_OPTIONS),
                                  *([f"--arch={specification.architecture}"] if specification.architecture else []),
                                  "--include=" + ",".join(specification.packages), specification.suite, str(root),
                                  mirror], capture_output=True, text=True, timeout=900)
    assert debootstrap.returncode == 0, debootstrap.stderr[-3000:]
    for name in MERGED_USR:
        if (root / "usr" / name).is_dir() and not os.path.lexists(root / name):
            (root / name).symlink_to(f"usr/{name}")
    for site in specification.sites:
        pip = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
                              "--no-deps", "--only-binary=:all:", "--target", str(root / site.folder),
                              *(f"--platform={p}" for p in site.platforms), "--python-version", site.python,
                              "--implementation", "cp", *site.requirements],
                             capture_output=True, text=True, timeout=900,
                             env={**os.environ, "PIP_ROOT_USER_ACTION": "ignore"})
        assert pip.returncode == 0, pip.stderr[-3000:]
    (folder / "specification.json").write_text(json.dumps(asdict(specification)))


def _intact(folder: Path, specification: Specification) -> bool:
    marker = folder / "specification.json"
    return (marker.is_file() and json.loads(marker.read_text()) == json.loads(json.dumps(asdict(specification)))
            and all((folder / "root" / "usr" / "bin" / f"python{s.python}").is_file()
                    and (folder / "root" / s.folder).is_dir() for s in specification.sites))


def cached_root(specification: Specification, prepare=None) -> DebianRoot:
    """The root of ``specification``: taken from the cache, or made there (as root: mmdebstrap, chroot);
    ``prepare()``, if given, runs first under the cache's lock (what the machine needs to run the root's
    programs)."""
    import fcntl
    import shutil

    from dsc_fmu.fmubuild.bundle.windows import cache_folder
    from wine import required

    if os.geteuid() != 0:
        required(f"the {specification.name} root needs root (chroot)")
    for tool in ("mmdebstrap", "chroot"):
        if not shutil.which(tool, path=SYSTEM_PATH):
            required(f"{tool} is not installed (Debian: apt-get install mmdebstrap)")
    key = specification.key()
    cache = cache_folder() / specification.name
    cache.mkdir(parents=True, exist_ok=True)
    folder = cache / key
    with open(cache / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if prepare:
            prepare()
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
    return DebianRoot(folder / "root", specification)


def copied(fmus: dict, folder: Path) -> dict:
    """The FMUs copied into ``folder``, by name: both sides run these files."""
    import shutil

    folder.mkdir()
    return {name: Path(shutil.copy(path, folder / Path(path).name)) for name, path in fmus.items()}


def assert_identical(inside: np.ndarray, host: np.ndarray, columns) -> None:
    """Every column of ``columns`` equal to the last bit (else the first differing row of each that differs)."""
    differing = [c for c in columns if inside[c].tobytes() != host[c].tobytes()]
    assert not differing, {c: int(np.flatnonzero(inside[c] != host[c])[0]) for c in differing}


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


# Tasks: each takes the FMUs (paths by name) and strings, and returns arrays and JSON values by name.

def paper_cosimulation(fmus: dict, traced: str = "on") -> dict:
    """The paper's scenario for ``PAPER_STOP`` s through ``dsc_fmu.cosimulate``, the FMUs' parameter ``traced`` set
    to ``traced`` ("on": their models in the C traced from them, "off": in Python)."""
    from dataclasses import replace

    from dsc_fmu import cosimulate, load_scenario
    from dsc_fmu.models.parameters import TRACED

    scenario = load_scenario("paper").with_simulation(stop_time=PAPER_STOP)
    scenario = replace(scenario, **{part: {**getattr(scenario, part), "traced": TRACED.index(traced)}
                                    for part in ("plant", "controller", "reference")})
    run = cosimulate(scenario, fmus)
    return {"result": run.result, "steps": run.steps}


def served_paper_cosimulation(fmus: dict) -> dict:
    """``paper_cosimulation``, and which CPython ran the FMUs' Python code: this process's version and
    executable, and the files of the FMUs' resources whose code it executed (seen by an audit hook on
    ``exec``, which importing a module's code raises). For a process of its own: the hook stays."""
    executed = set()

    def hook(event: str, arguments: tuple) -> None:
        filename = getattr(arguments[0], "co_filename", "") if event == "exec" else ""
        if "/resources/" in filename:
            executed.add(filename.partition("/resources/")[2])

    sys.addaudithook(hook)
    outputs = paper_cosimulation(fmus)
    return {**outputs, "version": list(sys.version_info[:3]), "executable": sys.executable,
            "executed": sorted(executed)}


def paper_model_exchange(fmus: dict) -> dict:
    """The paper's scenario for ``EXCHANGE_STOP`` s through ``dsc_fmu.simulate_model_exchange``."""
    from dsc_fmu import load_scenario, simulate_model_exchange

    run = simulate_model_exchange(load_scenario("paper"), fmus, stop_time=EXCHANGE_STOP, tolerance=EXCHANGE_TOLERANCE)
    return {"result": run.result, "evaluations": run.evaluations}


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


def main(task: str, fmus: str, out: str, *options: str) -> None:
    """Run the function ``task`` ("module.function") on the FMUs (a JSON object of paths by name) and write its
    arrays as ``.npy`` and its other values to ``values.json`` in ``out``."""
    import importlib

    module, _, function = task.rpartition(".")
    outputs = getattr(importlib.import_module(module), function)(json.loads(fmus), *options)
    values = {}
    for key, value in outputs.items():
        if isinstance(value, np.ndarray):
            np.save(Path(out) / f"{key}.npy", value)
        else:
            values[key] = value
    (Path(out) / "values.json").write_text(json.dumps(values))


if __name__ == "__main__":
    main(*sys.argv[1:])
