"""The platforms the FMUs carry binaries for, and where in an FMU each one's binary is: one table for the
builder (``fmubuild.binary``, which adds how to compile for each) and for the masters that load the FMUs."""

from __future__ import annotations

import platform
import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = ["PLATFORMS", "LINUX", "LINUX_AARCH64", "WINDOWS", "MACOS_ARM64", "MACOS_X86_64", "library_path"]


@dataclass(frozen=True)
class Platform:
    """An operating system on a CPU (``os``, ``cpu`` as FMI 3.0's platform tuples write them), and the folders of an
    FMU that hold its binary: for FMI 2.0 and 3.0, the folders under ``binaries/``, the one importers read
    first. Platforms that share a folder share one file: macOS's two CPUs in FMI 2.0's ``darwin64`` (a universal
    binary). ``suffix``: ``.so``, ``.dll``, ``.dylib``.
    """

    os: str
    cpu: str
    folders: tuple[tuple[str, ...], tuple[str, ...]]
    suffix: str

    @property
    def name(self) -> str:
        """The FMI 3.0 platform tuple (``x86_64-linux``)."""
        return f"{self.cpu}-{self.os}"

    def folder(self, fmi_version: int) -> str:
        """The binary's folder under ``binaries/``; the first where several hold it."""
        return self.folders[fmi_version - 2][0]

    def file(self, fmi_version: int, model_identifier: str) -> str:
        """The binary's path in an FMU, with ``/``; the first where several hold it."""
        return self.files(fmi_version, model_identifier)[0]

    def files(self, fmi_version: int, model_identifier: str) -> list[str]:
        """Every path of the binary in an FMU, with ``/``: first the one importers read first."""
        return [f"binaries/{folder}/{model_identifier}{self.suffix}" for folder in self.folders[fmi_version - 2]]


LINUX = Platform("linux", "x86_64", (("linux64",), ("x86_64-linux",)), ".so")
# FMI 2.0.4 names folders for x86 only and asks for FMI 3.0's platform tuples elsewhere: aarch64 Linux in
# aarch64-linux (linux64 is x86-64's), macOS's arm64 in darwin64's universal binary and, alone, in
# aarch64-darwin, where importers that know Apple Silicon look (docs/other-tools.md, "Platforms").
LINUX_AARCH64 = Platform("linux", "aarch64", (("aarch64-linux",), ("aarch64-linux",)), ".so")
WINDOWS = Platform("windows", "x86_64", (("win64",), ("x86_64-windows",)), ".dll")
MACOS_ARM64 = Platform("darwin", "aarch64", (("darwin64", "aarch64-darwin"), ("aarch64-darwin",)), ".dylib")
MACOS_X86_64 = Platform("darwin", "x86_64", (("darwin64",), ("x86_64-darwin",)), ".dylib")
PLATFORMS = (LINUX, LINUX_AARCH64, WINDOWS, MACOS_ARM64, MACOS_X86_64)
_SYSTEMS = {"linux": "linux", "win32": "windows", "darwin": "darwin"}
_CPUS = {"x86_64": "x86_64", "amd64": "x86_64", "aarch64": "aarch64", "arm64": "aarch64"}


def host_platform() -> Platform | None:
    """The platform this runs on: one of ``PLATFORMS``, or None if the FMUs carry no binary for this system and CPU."""
    here = (_SYSTEMS.get(sys.platform), _CPUS.get(platform.machine().lower()))
    return next((candidate for candidate in PLATFORMS if (candidate.os, candidate.cpu) == here), None)


def library_path(unzipped: Path | str, fmi_version: int, model_identifier: str) -> str | None:
    """The binary of this platform in an unzipped FMU of ours, where fmpy would not find it by itself.

    fmpy 0.3 loads FMI 2.0 binaries from ``linux64`` on aarch64 Linux too (it knows FMI 2.0's folder
    names only), where ours is in ``aarch64-linux``; everywhere else its own choice is ours.

    Parameters
    ----------
    unzipped : pathlib.Path or str
        The FMU's folder.
    fmi_version : {2, 3}
        Its FMI version.
    model_identifier : str
        Its model identifier.

    Returns
    -------
    str or None
        The path for fmpy's ``libraryPath``, or None: fmpy's own.
    """
    here = host_platform()
    if fmi_version != 2 or here is not LINUX_AARCH64:
        return None
    return str(Path(unzipped) / here.file(fmi_version, model_identifier))
