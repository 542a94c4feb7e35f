"""Where the FMUs of each FMI version go, and which version a folder holds: nothing replaces FMUs of another."""

from __future__ import annotations

from pathlib import Path

from ..errors import FmiVersionError
from ..identity import fmu_fmi_version
from ..registry import FMUS

__all__ = ["DEFAULT_FMU_DIR", "DEFAULT_FMU_DIRS", "FMI_VERSIONS", "DEFAULT_FMI_VERSION"]

DEFAULT_FMU_DIR = Path("build") / "fmus"
DEFAULT_FMU_DIRS = {2: DEFAULT_FMU_DIR, 3: Path("build") / "fmus3"}
FMI_VERSIONS = (2, 3)
DEFAULT_FMI_VERSION = 2  # where nothing says otherwise: neither the caller nor FMUs already built
_DECLARED = {"2.0": 2, "3.0": 3}  # a modelDescription's fmiVersion -> the FMI version


def check_fmi_version(fmi_version: int) -> int:
    """``fmi_version``, checked: ValueError unless 2 or 3."""
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"fmi_version = {fmi_version!r} is not allowed; allowed: 2 or 3")
    return fmi_version


def default_fmu_dir(fmi_version: int = DEFAULT_FMI_VERSION) -> Path:
    """``build/fmus`` (FMI 2.0) or ``build/fmus3`` (3.0), relative to the working directory; ValueError for another
    version."""
    return DEFAULT_FMU_DIRS[check_fmi_version(fmi_version)]


def resolve_fmu_dir(out_dir: Path | str | None = None, fmi_version: int | None = None) -> tuple[Path, int]:
    """The folder of the three FMUs (default ``default_fmu_dir``) and their FMI version, checked so that nothing
    replaces FMUs of another.

    The version is ``fmi_version`` if given (ValueError unless 2 or 3), else the ``fmiVersion`` of the FMUs the
    folder holds (only the three ``<name>.fmu`` that read count), else ``DEFAULT_FMI_VERSION``. FmiVersionError,
    in one line, if the folder holds FMUs of another version than ``fmi_version``, of two versions, or of
    neither 2.0 nor 3.0.
    """
    asked = None if fmi_version is None else check_fmi_version(fmi_version)
    folder = Path(out_dir) if out_dir is not None else default_fmu_dir(asked or DEFAULT_FMI_VERSION)
    found = sorted({fmu_fmi_version(folder / f"{name}.fmu") for name in FMUS} - {None})
    if len(found) > 1:
        raise FmiVersionError(f"{folder} holds FMUs of FMI {' and '.join(found)}; allowed: a folder whose FMUs "
                              "share one FMI version")
    held = _DECLARED.get(found[0], found[0]) if found else None
    if held is not None and held not in FMI_VERSIONS:
        raise FmiVersionError(f"{folder} holds FMI {found[0]} FMUs; allowed: a folder of FMI 2.0 or 3.0 FMUs, or "
                              "one without FMUs")
    if held is not None and asked not in (None, held):
        raise FmiVersionError(f"fmi_version = {asked} is not allowed for {folder}, which holds FMI {found[0]} FMUs "
                              f"(they would be replaced); allowed: {held}, or another folder")
    return folder, asked or held or DEFAULT_FMI_VERSION
