"""The sweep's cache: keys of runs and reference solutions, and their files, written atomically.

Layout inside a sweep's output folder::

    cache/runs/<key>.json         one row (``rows.ROW_KEYS``), written last: its presence marks the entry
    cache/runs/<key>.npz          the run's trajectory (``TRAJECTORY`` columns, as recorded)
    cache/references/<key>.npz    a reference solution (``REFERENCE_COLUMNS`` on a 1 ms grid)

A run's key is the SHA-256 of everything that determines its row: the scenario's content after the
case is applied (parameter values and the simulation settings stop time, step, order, output
interval and bound; not its file or name), the case, the FMUs' build ids, the key of its reference
solution and ``ROW_VERSION``. A reference's key leaves out what the monolithic ODE does not see (the
step, order, output interval, bound and the controller's discretisation) and adds the reference
grid, the solver settings and a hash of the Python code the reference and the metrics run.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import json
import os
import tempfile
from importlib.metadata import version
from pathlib import Path

import numpy as np

from ..build.fmus import fmu_build_id
from ..registry import fmu_files
from ..scenario import TABLES, Scenario
from .cases import Case, apply

__all__ = [
    "ROW_VERSION", "REFERENCE_GRID", "REFERENCE_SETTINGS", "fmu_identities", "scenario_content", "case_key",
    "reference_key", "SweepCache", "atomic_write", "TRAJECTORY", "REFERENCE_COLUMNS", "load_trajectory", "load_reference",
]

ROW_VERSION = 2  # bump when the definition of a row changes
REFERENCE_GRID = 1e-3  # s: the reference solution's time grid, interpolated at the run's times
REFERENCE_SETTINGS = {"rtol": 1e-10, "atol": 1e-10, "method": "DOP853"}
TRAJECTORY = ("time", "x", "y", "theta", "x_r", "y_r", "theta_r", "u1", "u2")
REFERENCE_COLUMNS = ("time", "x", "y", "theta", "u1", "u2")
_PACKAGE = Path(__file__).parents[1]
_CODE = ("cosim/reference_solution.py", "cosim/signals.py", "cosim/metrics.py", "models")


def _digest(data) -> str:
    """SHA-256 (hex) of ``data`` as canonical JSON (sorted keys, shortest exact float repr)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


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
    """Each FMU's build id (``fmu_build_id``), or the SHA-256 of its file if it has none."""
    return {name: fmu_build_id(path) or "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()
            for name, path in sorted(fmu_files(fmu_paths).items())}


def scenario_content(scenario: Scenario) -> dict:
    """What of ``scenario`` determines a run: every parameter value and the simulation settings."""
    return {"simulation": dataclasses.asdict(scenario.simulation), **{t: getattr(scenario, t) for t in TABLES}}


def reference_key(scenario: Scenario, case: Case) -> str:
    """Key of the reference solution of ``case`` applied to ``scenario`` (independent of the step,
    the order and the discretisation)."""
    content = scenario_content(apply(scenario, case))
    content["simulation"] = {"stop_time": content["simulation"]["stop_time"]}
    content["controller"] = {k: v for k, v in content["controller"].items() if k != "discretization"}
    return _digest({"reference": content, "grid": REFERENCE_GRID, "solver": REFERENCE_SETTINGS, "code": _code_hash()})


def case_key(scenario: Scenario, case: Case, fmu_build_ids: dict) -> str:
    """Key of the row of ``case`` run on ``scenario`` with FMUs of the given build ids (by name)."""
    return _digest({
        "scenario": scenario_content(apply(scenario, case)),
        "case": dataclasses.asdict(case),
        "fmus": dict(sorted(fmu_build_ids.items())),
        "reference": reference_key(scenario, case),
        "row_version": ROW_VERSION,
    })


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and ``os.replace``: never a partial file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, partial = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(data)
        os.replace(partial, path)
    except BaseException:
        Path(partial).unlink(missing_ok=True)
        raise


def _npz(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{name: array[name] for name in array.dtype.names})
    return buffer.getvalue()


def _from_npz(path: Path) -> np.ndarray:
    with np.load(path) as data:
        names = list(data.files)
        columns = {name: data[name] for name in names}
    array = np.zeros(len(columns[names[0]]) if names else 0, dtype=[(name, np.float64) for name in names])
    for name in names:
        array[name] = columns[name]
    return array


class SweepCache:
    """The cache folder of a sweep's output folder ``out_dir`` (created on the first write)."""

    def __init__(self, out_dir: Path | str):
        self.root = Path(out_dir) / "cache"
        self.runs, self.references = self.root / "runs", self.root / "references"

    def row(self, key: str) -> dict | None:
        """The cached row of ``key``, or None if there is no complete entry."""
        path = self.runs / f"{key}.json"
        if not (path.is_file() and path.with_suffix(".npz").is_file()):
            return None
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            return None

    def store_run(self, key: str, row: dict, trajectory: np.ndarray) -> None:
        """Cache a run: its trajectory, then its row (the row's file completes the entry)."""
        atomic_write(self.runs / f"{key}.npz", _npz(trajectory))
        atomic_write(self.runs / f"{key}.json", json.dumps(row).encode())

    def trajectory(self, key: str) -> np.ndarray:
        """The trajectory of the run cached under ``key`` (structured array, ``time`` first)."""
        return _from_npz(self.runs / f"{key}.npz")

    def reference(self, key: str) -> np.ndarray | None:
        """The cached reference solution of ``key``, or None."""
        path = self.references / f"{key}.npz"
        try:
            return _from_npz(path) if path.is_file() else None
        except (OSError, ValueError, KeyError, EOFError):
            return None

    def store_reference(self, key: str, reference: np.ndarray) -> None:
        """Cache a reference solution."""
        atomic_write(self.references / f"{key}.npz", _npz(reference))


def load_trajectory(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray:
    """The trajectory (``TRAJECTORY`` columns, as recorded; up to the failure for a diverged run)
    of a run cached in the sweep folder ``out_dir``, given its row or its key."""
    key = row_or_key["key"] if isinstance(row_or_key, dict) else row_or_key
    return SweepCache(out_dir).trajectory(key)


def load_reference(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray | None:
    """The reference solution (``REFERENCE_COLUMNS`` every ``REFERENCE_GRID`` s) of a row cached in
    the sweep folder ``out_dir``, given the row or its ``reference_key``; None if the solver failed."""
    key = row_or_key["reference_key"] if isinstance(row_or_key, dict) else row_or_key
    return SweepCache(out_dir).reference(key)
