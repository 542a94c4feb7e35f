"""The sweep's cache: keys of runs and reference solutions, and their entries, written atomically and
verified whenever they are read.

Layout inside a sweep's output folder::

    cache/runs/<key>.npz          the run's trajectory (``TRAJECTORY`` columns, as recorded)
    cache/runs/<key>.json         its record, written last (its presence marks the entry):
                                  {"row": the row (rows.ROW_KEYS), "trajectory_sha256": of the .npz file,
                                   "provenance": {...}, "checksum": ...}
    cache/references/<key>.npz    a reference solution (``REFERENCE_COLUMNS`` on a ``REFERENCE_GRID`` grid)
    cache/references/<key>.json   its record: {"reference_sha256": ..., "provenance": {...}, "checksum": ...}

``provenance`` says what wrote the entry: its key, dsc-fmu's version, the FMUs' identities (runs
only), the Python, NumPy and SciPy versions and the time. ``checksum`` is the SHA-256 of the
canonical JSON (sorted keys, no spaces, NaN as ``NaN``) of the record without it. An entry verifies
if its record parses, has this layout, matches its checksum and its key, and its .npz matches its
SHA-256 and holds exactly the expected columns, 1-D floats of one length, without pickles. An entry
that exists but does not verify (damaged, edited, of an older layout) is a ``CacheEntryError``; a
sweep recomputes it and says so in one ``CacheWarning``. An .npz without its record is a write that
was interrupted: a plain miss, overwritten.

A run's key (``case_key``) is the SHA-256 of everything that determines its row: the scenario's
content after the case is applied (parameter values and every simulation setting, the stability
definition included, so another ``--stability`` runs the cases again; not its file or name), the
case, the FMUs' identities, the key of its reference solution and ``ROW_VERSION``. A reference's key
(``reference_key``) leaves out what the monolithic ODE does not see (the step, order, output
interval, bound and the controller's discretisation) and adds the reference grid, the solver
settings and a hash of the Python code the reference and the metrics run.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import json
import platform
import zipfile
import zlib
from datetime import datetime, timezone
from importlib.metadata import version
from pathlib import Path

import numpy as np

from .. import __version__
from ..files import atomic_write
from ..identity import fmu_build_id
from ..registry import fmu_files
from ..scenario import TABLES, Reference, Scenario
from .cases import Case, SweepError, apply

__all__ = [
    "ROW_VERSION", "REFERENCE_GRID", "REFERENCE_SETTINGS", "TRAJECTORY", "REFERENCE_COLUMNS", "CacheWarning",
    "CacheEntryError", "load_trajectory", "load_reference",
]

ROW_VERSION = 5  # bump when the definition of a row changes
REFERENCE_GRID = 1e-3  # s: the reference solution's time grid, interpolated at the run's times
REFERENCE_SETTINGS = {"rtol": 1e-10, "atol": 1e-10, "method": "DOP853"}
TRAJECTORY = ("time", "x", "y", "theta", "x_r", "y_r", "theta_r", "u1", "u2")
REFERENCE_COLUMNS = ("time", "x", "y", "theta", "u1", "u2")
_RUN_FIELDS = ("row", "trajectory_sha256", "provenance")
_REFERENCE_FIELDS = ("reference_sha256", "provenance")
_PACKAGE = Path(__file__).parents[1]
_CODE = ("cosim/reference_solution.py", "cosim/signals.py", "cosim/metrics.py", "models")


class CacheWarning(UserWarning):
    """Cache entries that did not verify were recomputed (one warning per sweep)."""


class CacheEntryError(SweepError):
    """A cache entry that is missing or does not verify; its message is ``"<path>: <reason>"``.

    Parameters
    ----------
    path : pathlib.Path
        The file at fault.
    reason : str
        Why, on one line.
    """

    def __init__(self, path: Path, reason: str):
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = Path(path), reason


def _digest(data) -> str:
    """SHA-256 of ``data`` as canonical JSON (sorted keys, shortest exact float repr)."""
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()).hexdigest()


def _checksum(record: dict) -> str:
    """SHA-256 of ``record`` as canonical JSON, NaN and infinities written as Python's json does."""
    return hashlib.sha256(json.dumps(record, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


@functools.cache
def _code_hash() -> str:
    """Hash of the Python code that computes a reference solution and the metrics of a row."""
    digest = hashlib.sha256(f"scipy {version('scipy')}".encode())
    for name in _CODE:
        path = _PACKAGE / name
        for file in sorted(path.glob("*.py")) if path.is_dir() else [path]:
            digest.update(file.name.encode())
            digest.update(file.read_bytes())
    return digest.hexdigest()


def fmu_identities(fmu_paths: dict) -> dict[str, str]:
    """By FMU name, sorted: its build id (``identity.fmu_build_id``), or ``"sha256:<hex>"`` of its file."""
    return {name: fmu_build_id(path) or "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()
            for name, path in sorted(fmu_files(fmu_paths).items())}


def _content(scenario: Scenario) -> dict:
    """What of a scenario determines a run: its simulation settings and parameter values, not its name or file."""
    return {"simulation": dataclasses.asdict(scenario.simulation), **{t: getattr(scenario, t) for t in TABLES}}


def reference_key(scenario: Scenario, case: Case, fmu_build_ids: dict) -> str:
    """The key of the reference solution of ``case`` on ``scenario``, with FMUs of ``fmu_build_ids``
    (``fmu_identities``)."""
    content = _content(apply(scenario, case))
    kind = content["simulation"]["reference"]
    content["simulation"] = {"stop_time": content["simulation"]["stop_time"]}
    content["controller"] = {k: v for k, v in content["controller"].items() if k != "discretization"}
    key = {"reference": content, "grid": REFERENCE_GRID, "solver": REFERENCE_SETTINGS, "code": _code_hash()}
    if Reference(kind).through_fmus:
        key.update({"through": kind, "fmus": dict(sorted(fmu_build_ids.items()))})
    return _digest(key)


def case_key(scenario: Scenario, case: Case, fmu_build_ids: dict) -> str:
    """The key of the row of ``case`` on ``scenario``, run with FMUs of ``fmu_build_ids`` (``fmu_identities``)."""
    return _digest({
        "scenario": _content(apply(scenario, case)),
        "case": dataclasses.asdict(case),
        "fmus": dict(sorted(fmu_build_ids.items())),
        "reference": reference_key(scenario, case, fmu_build_ids),
        "row_version": ROW_VERSION,
    })


def _provenance(key: str, fmus: dict | None = None) -> dict:
    written = {"key": key, "dsc_fmu": __version__, "python": platform.python_version(), "numpy": np.__version__,
               "scipy": version("scipy"), "written": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    return written if fmus is None else {**written, "fmus": dict(sorted(fmus.items()))}


def _write_entry(folder: Path, key: str, array: np.ndarray, columns: tuple, leading: dict, sha256_field: str,
                 written_by: dict) -> None:
    """``array`` to ``folder/<key>.npz``, then its record to ``folder/<key>.json``."""
    if array.dtype.names != columns:
        raise ValueError(f"columns {array.dtype.names} are not allowed here; allowed: {columns}")
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{name: array[name] for name in columns})
    data = buffer.getvalue()
    record = {**leading, sha256_field: hashlib.sha256(data).hexdigest(), "provenance": written_by}
    record["checksum"] = _checksum(record)
    atomic_write(folder / f"{key}.npz", data)
    atomic_write(folder / f"{key}.json", json.dumps(record, indent=1).encode())


def _read_bytes(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as error:
        raise CacheEntryError(path, f"cannot be read ({error.strerror or type(error).__name__})") from None


def _read_record(path: Path, key: str, fields: tuple) -> dict | None:
    """The record in ``path`` (without its checksum), verified; None if there is no such file."""
    text = _read_bytes(path)
    if text is None:
        return None
    try:
        record = json.loads(text)
    except (ValueError, RecursionError):
        raise CacheEntryError(path, "not JSON") from None
    if not isinstance(record, dict) or sorted(record) != sorted((*fields, "checksum")):
        raise CacheEntryError(path, "not an entry record (an older cache layout, or edited)")
    if record.pop("checksum") != _checksum(record):
        raise CacheEntryError(path, "does not match its checksum (edited or damaged)")
    if not isinstance(record["provenance"], dict) or record["provenance"].get("key") != key:
        raise CacheEntryError(path, "written for another key")
    return record


def _read_npz(path: Path, sha256, columns: tuple) -> np.ndarray:
    """The structured array in ``path`` if the file's SHA-256 is ``sha256`` and it holds exactly
    ``columns``, 1-D floats of one length (no pickles)."""
    data = _read_bytes(path)
    if data is None:
        raise CacheEntryError(path, "missing")
    if hashlib.sha256(data).hexdigest() != sha256:
        raise CacheEntryError(path, "does not match the SHA-256 in its record (damaged or replaced)")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as loaded:
            arrays = {name: loaded[name] for name in loaded.files}
    except (OSError, ValueError, EOFError, KeyError, TypeError, zipfile.BadZipFile, zlib.error) as error:
        raise CacheEntryError(path, f"not a readable .npz file ({type(error).__name__})") from None
    if tuple(arrays) != columns:
        raise CacheEntryError(path, f"holds the columns {', '.join(arrays) or 'none'}; expected {', '.join(columns)}")
    if len({a.shape for a in arrays.values()}) != 1 or any(a.ndim != 1 or a.dtype != np.float64
                                                           for a in arrays.values()):
        raise CacheEntryError(path, "its columns are not 1-D float arrays of one length")
    array = np.zeros(len(arrays[columns[0]]), dtype=[(name, np.float64) for name in columns])
    for name in columns:
        array[name] = arrays[name]
    return array


class SweepCache:
    """The cache of the sweep folder ``out_dir``: a read gives None if there is no entry, and raises
    CacheEntryError if it does not verify."""

    def __init__(self, out_dir: Path | str):
        self.root = Path(out_dir) / "cache"
        self.runs, self.references = self.root / "runs", self.root / "references"

    def _run_record(self, key: str) -> dict | None:
        path = self.runs / f"{key}.json"
        record = _read_record(path, key, _RUN_FIELDS)
        if record is not None and not (isinstance(record["row"], dict) and record["row"].get("key") == key):
            raise CacheEntryError(path, "its row is not the row of this key")
        return record

    def row(self, key: str) -> dict | None:
        """The row of the run ``key`` (``case_key``), its trajectory verified too."""
        record = self._run_record(key)
        if record is not None:
            _read_npz(self.runs / f"{key}.npz", record["trajectory_sha256"], TRAJECTORY)
        return record and record["row"]

    def trajectory(self, key: str) -> np.ndarray:
        """The ``TRAJECTORY`` of the run ``key``; CacheEntryError if it is not cached."""
        record = self._run_record(key)
        if record is None:
            raise CacheEntryError(self.runs / f"{key}.json", "missing: no run of this key is cached")
        return _read_npz(self.runs / f"{key}.npz", record["trajectory_sha256"], TRAJECTORY)

    def store_run(self, key: str, row: dict, trajectory: np.ndarray, fmus: dict) -> None:
        """Cache the run ``key``: its ``TRAJECTORY``, then its record (``fmus``: ``fmu_identities``)."""
        _write_entry(self.runs, key, trajectory, TRAJECTORY, {"row": row}, "trajectory_sha256", _provenance(key, fmus))

    def reference(self, key: str) -> np.ndarray | None:
        """The reference solution ``key`` (``reference_key``)."""
        record = _read_record(self.references / f"{key}.json", key, _REFERENCE_FIELDS)
        return record and _read_npz(self.references / f"{key}.npz", record["reference_sha256"], REFERENCE_COLUMNS)

    def store_reference(self, key: str, reference: np.ndarray) -> None:
        """Cache the reference solution ``key``: its ``REFERENCE_COLUMNS``, then its record."""
        _write_entry(self.references, key, reference, REFERENCE_COLUMNS, {}, "reference_sha256", _provenance(key))


def load_trajectory(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray:
    """The trajectory of a run cached in a sweep folder.

    Parameters
    ----------
    out_dir : pathlib.Path or str
        The sweep folder.
    row_or_key : dict or str
        The run's row, or its key.

    Returns
    -------
    numpy.ndarray
        Its ``TRAJECTORY`` columns as recorded, ``time`` (s) first; up to the failure for a diverged run.

    Raises
    ------
    CacheEntryError
        One line, if the run is not cached or its entry does not verify.
    """
    return SweepCache(out_dir).trajectory(row_or_key["key"] if isinstance(row_or_key, dict) else row_or_key)


def load_reference(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray | None:
    """The reference solution of a row cached in a sweep folder.

    Parameters
    ----------
    out_dir : pathlib.Path or str
        The sweep folder.
    row_or_key : dict or str
        The row, or its ``reference_key``.

    Returns
    -------
    numpy.ndarray or None
        Its ``REFERENCE_COLUMNS`` every ``REFERENCE_GRID`` s; None if the solver failed (none is cached).

    Raises
    ------
    CacheEntryError
        One line, if the entry does not verify.
    """
    return SweepCache(out_dir).reference(row_or_key["reference_key"] if isinstance(row_or_key, dict) else row_or_key)
