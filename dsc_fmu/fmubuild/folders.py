"""Where the FMUs of each FMI version go, and which version a folder holds: nothing replaces FMUs of another."""

from __future__ import annotations

from pathlib import Path

from ..errors import FmiVersionError
from ..identity import fmu_fmi_version
from ..registry import FMUS

__all__ = ["DEFAULT_FMU_DIR", "DEFAULT_FMU_DIRS", "FMI_VERSIONS", "DEFAULT_FMI_VERSION", "check_fmi_version",
           "default_fmu_dir", "resolve_fmu_dir"]

DEFAULT_FMU_DIR = Path("build") / "fmus"
DEFAULT_FMU_DIRS = {2: DEFAULT_FMU_DIR, 3: Path("build") / "fmus3"}
FMI_VERSIONS = (2, 3)
DEFAULT_FMI_VERSION = 2  # where nothing says otherwise: neither the caller nor FMUs already built
_DECLARED = {"2.0": 2, "3.0": 3}  # a modelDescription's fmiVersion -> the FMI version


def check_fmi_version(fmi_version: int) -> int:
    """An FMI version the FMUs are built for, checked.

    Parameters
    ----------
    fmi_version : {2, 3}
        The FMI version (``ValueError`` for another).

    Returns
    -------
    int
        ``fmi_version``.
    """
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"fmi_version = {fmi_version!r} is not allowed; allowed: 2 or 3")
    return fmi_version


def default_fmu_dir(fmi_version: int = DEFAULT_FMI_VERSION) -> Path:
    """Where the FMUs of an FMI version are built by default.

    Parameters
    ----------
    fmi_version : {2, 3}, optional
        The FMI version (``ValueError`` for another). Default 2.

    Returns
    -------
    pathlib.Path
        ``build/fmus`` (2.0) or ``build/fmus3`` (3.0), relative to the working directory.
    """
    return DEFAULT_FMU_DIRS[check_fmi_version(fmi_version)]


def resolve_fmu_dir(out_dir: Path | str | None = None, fmi_version: int | None = None) -> tuple[Path, int]:
    """The folder of the three FMUs and their FMI version, checked so that nothing replaces FMUs of another.

    The version is ``fmi_version`` if given, else the ``fmiVersion`` of the FMUs the folder holds (only
    the three ``<name>.fmu`` that read count), else ``DEFAULT_FMI_VERSION``.

    Parameters
    ----------
    out_dir : pathlib.Path or str or None, optional
        The folder. Default None: ``default_fmu_dir`` of the version.
    fmi_version : {2, 3} or None, optional
        The FMI version asked for (``ValueError`` for another). Default None: the folder's.

    Returns
    -------
    tuple of (pathlib.Path, int)
        The folder and the FMI version of the FMUs to find or build there.

    Raises
    ------
    FmiVersionError
        In one line, if the folder holds FMUs of another version than ``fmi_version``, of two
        versions, or of neither 2.0 nor 3.0.
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
