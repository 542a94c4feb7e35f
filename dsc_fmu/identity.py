"""What identifies an FMU build: the record its builder writes into it, read without the builder."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .errors import FmiVersionError

__all__ = ["BUILD_ID_FILE", "fmu_bundled_python", "fmu_untraced"]

# Written by ``fmubuild.fmus`` into every FMU: ``{"source_hash", "dsc_fmu", "fmi_version", "traced"}`` (``traced``:
# ``{"untraceable": {C name: reason}}``, or null for a build without the traced C), and ``"python"`` (the version of
# the CPython it carries for each platform) in one built with ``--bundle-python``.
BUILD_ID_FILE = "resources/dsc_fmu_build.json"


def fmu_build_id(fmu: Path) -> str | None:
    """The ``source_hash`` of an FMU's ``BUILD_ID_FILE``; None if it is not one of ours or not readable."""
    return _read(fmu, BUILD_ID_FILE, lambda data: json.loads(data)["source_hash"])


def fmu_bundled_python(fmu: Path) -> dict | None:
    """The CPythons an FMU of ours carries.

    Parameters
    ----------
    fmu : pathlib.Path
        An FMU file.

    Returns
    -------
    dict of str to str or None
        The full version by platform (``{"x86_64-linux": "3.11.7"}``); None if it carries none, is not one
        of ours or is not readable.
    """
    return _read(fmu, BUILD_ID_FILE, lambda data: json.loads(data).get("python"))


def fmu_untraced(fmu: Path) -> dict | None:
    """What of an FMU's model runs in Python, not in the C traced from it (docs/traced-c.md).

    Parameters
    ----------
    fmu : pathlib.Path
        An FMU file.

    Returns
    -------
    dict of str to str or None
        The reason by the name of each function that could not be traced (empty: everything is); None for an FMU
        built without the traced C (``--no-traced``), not one of ours or not readable.
    """
    return _read(fmu, BUILD_ID_FILE, lambda data: (json.loads(data).get("traced") or {}).get("untraceable"))


def fmu_fmi_version(fmu: Path) -> str | None:
    """The ``fmiVersion`` (``"2.0"``, ``"3.0"``) an FMU's ``modelDescription.xml`` declares, whoever built it; None if
    not readable."""
    return _read(fmu, "modelDescription.xml", lambda data: ET.fromstring(data).get("fmiVersion"))


def require_fmi2(fmus, why: str) -> None:
    """Refuse FMUs that declare another FMI version than 2.0, for a job that takes FMI 2.0 FMUs only: FmiVersionError
    ``"<path> is an FMI 3.0 FMU, not allowed here: <why>; allowed: FMI 2.0 FMUs"`` for the first.
    """
    for fmu in fmus:
        version = fmu_fmi_version(fmu)
        if version not in (None, "2.0"):
            raise FmiVersionError(f"{fmu} is an FMI {version} FMU, not allowed here: {why}; allowed: FMI 2.0 FMUs")


def _read(fmu: Path, name: str, parse):
    """``parse`` of the file ``name`` of an FMU, or None if anything is missing or not readable."""
    try:
        with zipfile.ZipFile(fmu) as archive:
            return parse(archive.read(name))
    except (OSError, KeyError, ValueError, ET.ParseError, zipfile.BadZipFile):
        return None
