"""What identifies an FMU build: the record its builder writes into it, read without the builder."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

__all__ = ["BUILD_ID_FILE", "fmu_build_id", "fmu_fmi_version"]

# Written by ``build.fmus`` into every FMU: ``{"source_hash", "dsc_fmu", "fmi_version"}``.
BUILD_ID_FILE = "resources/dsc_fmu_build.json"


def fmu_build_id(fmu: Path) -> str | None:
    """The source hash an FMU was built from.

    Parameters
    ----------
    fmu : pathlib.Path
        An FMU file.

    Returns
    -------
    str or None
        The ``source_hash`` of its ``BUILD_ID_FILE``, or None if it is not one of ours (or not readable).
    """
    try:
        with zipfile.ZipFile(fmu) as archive:
            return json.loads(archive.read(BUILD_ID_FILE))["source_hash"]
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None


def fmu_fmi_version(fmu: Path) -> str | None:
    """The FMI version an FMU declares, whoever built it.

    Parameters
    ----------
    fmu : pathlib.Path
        An FMU file.

    Returns
    -------
    str or None
        The ``fmiVersion`` of its ``modelDescription.xml`` (``"2.0"``, ``"3.0"``), or None if it has
        none (or is not readable).
    """
    try:
        with zipfile.ZipFile(fmu) as archive:
            return ET.fromstring(archive.read("modelDescription.xml")).get("fmiVersion")
    except (OSError, KeyError, ET.ParseError, zipfile.BadZipFile):
        return None
