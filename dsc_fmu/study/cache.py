"""The sweep's cache: keys of runs and reference solutions, and their entries, written atomically and
verified whenever they are read (docs/step-size-studies.md, "The cache": its layout and what a key hashes)."""

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

__all__ = ["ROW_VERSION", "REFERENCE_GRID", "REFERENCE_SETTINGS", "TRAJECTORY", "REFERENCE_COLUMNS", "CacheWarning"]

ROW_VERSION = 5  # bump when the definition of a row changes
REFERENCE_GRID = 1e-3  # s: the reference solution's time grid, interpolated at the run's times
REFERENCE_SETTINGS = {"rtol": 1e-10, "atol": 1e-10, "method": "DOP853"}
TRAJECTORY = ("time", "x", "y", "theta", "x_r", "y_r", "theta_r", "u1", "u2")
REFERENCE_COLUMNS = ("time", "x", "y", "theta", "u1", "u2")
_PACKAGE = Path(__file__).parents[1]
_CODE = ("cosim/reference_solution.py", "cosim/signals.py", "cosim/metrics.py", "models")


class CacheWarning(UserWarning):
    """Cache entries that did not verify were recomputed (one warning per sweep)."""


class CacheEntryError(SweepError):
    """A cache entry that is missing or does not verify: ``"<path>: <reason>"``, one line."""

    def __init__(self, path: Path, reason: str):
        super().__init__(f"{path}: {reason}")


def _checksum(data, allow_nan: bool = True) -> str:
    """SHA-256 of ``data`` as canonical JSON (sorted keys, no spaces, shortest exact float repr)."""
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=allow_nan).encode()
                          ).hexdigest()


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
    return _checksum(key, allow_nan=False)


def case_key(scenario: Scenario, case: Case, fmu_build_ids: dict) -> str:
    """The key of the row of ``case`` on ``scenario``, run with FMUs of ``fmu_build_ids`` (``fmu_identities``)."""
    return _checksum({
        "scenario": _content(apply(scenario, case)),
        "case": dataclasses.asdict(case),
        "fmus": dict(sorted(fmu_build_ids.items())),
        "reference": reference_key(scenario, case, fmu_build_ids),
        "row_version": ROW_VERSION,
    }, allow_nan=False)


def _read_bytes(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as error:
        raise CacheEntryError(path, f"cannot be read ({error.strerror or type(error).__name__})") from None


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

    def _read(self, folder: Path, key: str, sha256_field: str, columns: tuple, leading: tuple = ()) -> tuple | None:
        """The entry ``key`` of ``folder``, verified: its record (without checksum) and its array; None if there
        is no record."""
        path = folder / f"{key}.json"
        text = _read_bytes(path)
        if text is None:
            return None
        try:
            record = json.loads(text)
        except (ValueError, RecursionError):
            raise CacheEntryError(path, "not JSON") from None
        if not isinstance(record, dict) or sorted(record) != sorted((*leading, sha256_field, "provenance", "checksum")):
            raise CacheEntryError(path, "not an entry record (an older cache layout, or edited)")
        if record.pop("checksum") != _checksum(record):
            raise CacheEntryError(path, "does not match its checksum (edited or damaged)")
        if not isinstance(record["provenance"], dict) or record["provenance"].get("key") != key:
            raise CacheEntryError(path, "written for another key")
        if leading and not (isinstance(record["row"], dict) and record["row"].get("key") == key):
            raise CacheEntryError(path, "its row is not the row of this key")
        return record, _read_npz(folder / f"{key}.npz", record[sha256_field], columns)

    def _write(self, folder: Path, key: str, array: np.ndarray, columns: tuple, sha256_field: str,
               leading: dict, fmus: dict | None = None) -> None:
        """``array`` to ``folder/<key>.npz``, then its record to ``folder/<key>.json``."""
        if array.dtype.names != columns:
            raise ValueError(f"columns {array.dtype.names} are not allowed here; allowed: {columns}")
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **{name: array[name] for name in columns})
        data = buffer.getvalue()
        provenance = {"key": key, "dsc_fmu": __version__, "python": platform.python_version(),
                      "numpy": np.__version__, "scipy": version("scipy"),
                      "written": datetime.now(timezone.utc).isoformat(timespec="seconds")}
        if fmus is not None:
            provenance["fmus"] = dict(sorted(fmus.items()))
        record = {**leading, sha256_field: hashlib.sha256(data).hexdigest(), "provenance": provenance}
        record["checksum"] = _checksum(record)
        atomic_write(folder / f"{key}.npz", data)
        atomic_write(folder / f"{key}.json", json.dumps(record, indent=1).encode())

    def row(self, key: str) -> dict | None:
        """The row of the run ``key`` (``case_key``), its trajectory verified too."""
        entry = self._read(self.runs, key, "trajectory_sha256", TRAJECTORY, ("row",))
        return entry and entry[0]["row"]

    def trajectory(self, key: str) -> np.ndarray:
        """The ``TRAJECTORY`` of the run ``key``; CacheEntryError if it is not cached."""
        entry = self._read(self.runs, key, "trajectory_sha256", TRAJECTORY, ("row",))
        if entry is None:
            raise CacheEntryError(self.runs / f"{key}.json", "missing: no run of this key is cached")
        return entry[1]

    def store_run(self, key: str, row: dict, trajectory: np.ndarray, fmus: dict) -> None:
        """Cache the run ``key`` (``fmus``: ``fmu_identities``)."""
        self._write(self.runs, key, trajectory, TRAJECTORY, "trajectory_sha256", {"row": row}, fmus)

    def reference(self, key: str) -> np.ndarray | None:
        """The reference solution ``key`` (``reference_key``)."""
        entry = self._read(self.references, key, "reference_sha256", REFERENCE_COLUMNS)
        return entry and entry[1]

    def store_reference(self, key: str, reference: np.ndarray) -> None:
        self._write(self.references, key, reference, REFERENCE_COLUMNS, "reference_sha256", {})


def load_trajectory(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray:
    """The ``TRAJECTORY`` of a run (its row or key) cached in the sweep folder ``out_dir``, ``time`` (s) first;
    up to the failure for a diverged run. CacheEntryError if it is not cached or does not verify."""
    return SweepCache(out_dir).trajectory(row_or_key["key"] if isinstance(row_or_key, dict) else row_or_key)


def load_reference(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray | None:
    """The reference solution of a row (or of a ``reference_key``) cached in ``out_dir``: its
    ``REFERENCE_COLUMNS`` every ``REFERENCE_GRID`` s; None if the solver failed (none is cached).
    CacheEntryError if the entry does not verify."""
    return SweepCache(out_dir).reference(row_or_key["reference_key"] if isinstance(row_or_key, dict) else row_or_key)
