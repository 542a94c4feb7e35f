"""Sweep runs on a Dask distributed cluster: each worker process keeps one Cosimulator for all its runs.

The client ships the three FMU files once (scattered to every worker); a worker writes them into
a folder of its own (inside the worker's ``local_directory``) the first time it runs a case and
loads them there into a module-level Cosimulator, which later runs reuse. When the worker closes,
the ``CosimulatorCleanup`` plugin (and, failing that, ``atexit``) frees the instances and removes
that folder. Runs in one worker process are serialised by a lock: use one thread per worker
(``--nthreads 1``); extra threads bring nothing, as every FMI call into a pythonfmu FMU takes the GIL.
Workers need dsc-fmu installed with the Python version the FMUs were built with.
"""

from __future__ import annotations

import asyncio
import atexit
import hashlib
import shutil
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import distributed
from distributed.diagnostics.plugin import WorkerPlugin

from ..cosim.master import Cosimulator
from .cases import SweepError, check_scheduler
from .rows import compute_reference, lost_outcome, simulate

__all__ = ["connect", "run_on_cluster", "CosimulatorCleanup", "close_worker_simulator", "worker_status"]

_STATE: dict = {"digest": None, "simulator": None, "folder": None}
_LOCK = threading.Lock()
_EXIT_HOOK = []


async def _identity(address: str) -> dict:
    async with distributed.rpc(address, connection_args=distributed.Security().get_connection_args("client")) as peer:
        return await peer.identity()


def connect(address: str, timeout: float) -> distributed.Client:
    """A client of the scheduler at ``address``; SweepError (one line) if it is not an address
    (``check_scheduler``), cannot be reached, or what listens there does not answer as a Dask
    scheduler within ``timeout`` s (a ``distributed.Client`` of such a server waits forever)."""
    check_scheduler(address, timeout)
    try:
        with ThreadPoolExecutor(1) as thread:  # an event loop of its own, whatever loop the caller runs
            thread.submit(asyncio.run, asyncio.wait_for(_identity(address), timeout)).result()
        return distributed.Client(address, timeout=timeout, set_as_default=False)
    except TimeoutError:
        raise SweepError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s: "
                         "no Dask scheduler answered there") from None
    except (OSError, ValueError, TypeError) as error:
        reason = (str(error).splitlines() or [type(error).__name__])[0]
        raise SweepError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s: {reason}") from None


def close_worker_simulator() -> None:
    """Free this process's Cosimulator and remove its folder (the FMU files and their extraction)."""
    with _LOCK:
        simulator, folder = _STATE["simulator"], _STATE["folder"]
        _STATE.update(digest=None, simulator=None, folder=None)
        try:
            if simulator is not None:
                simulator.close()
        finally:
            if folder is not None:
                shutil.rmtree(folder, ignore_errors=True)


def worker_status() -> dict:
    """This process's Cosimulator: its folder (None if there is none) and how many runs it made;
    for ``client.run(worker_status)``."""
    simulator, folder = _STATE["simulator"], _STATE["folder"]
    return {"folder": None if folder is None else str(folder), "runs": 0 if simulator is None else simulator.runs}


class CosimulatorCleanup(WorkerPlugin):
    """Worker plugin: when the worker closes, free its Cosimulator and remove its folder."""

    name = "dsc-fmu-cosimulator-cleanup"
    idempotent = True

    def teardown(self, worker) -> None:
        close_worker_simulator()


def _simulator(fmus: dict[str, bytes]) -> Cosimulator:
    """This process's Cosimulator for the FMUs ``fmus`` (file contents by name); call with _LOCK held."""
    digest = hashlib.sha256(b"".join(hashlib.sha256(fmus[name]).digest() for name in sorted(fmus))).hexdigest()
    if _STATE["digest"] == digest:
        return _STATE["simulator"]
    simulator, folder = _STATE["simulator"], _STATE["folder"]
    if simulator is not None:  # other FMUs than last time: replace them
        simulator.close()
        shutil.rmtree(folder, ignore_errors=True)
        _STATE.update(digest=None, simulator=None, folder=None)
    try:
        base = distributed.get_worker().local_directory
    except ValueError:  # not inside a worker
        base = None
    folder = Path(tempfile.mkdtemp(prefix="dsc_fmu_sweep_", dir=base))
    try:
        paths = {}
        for name, data in fmus.items():
            paths[name] = folder / f"{name}.fmu"
            paths[name].write_bytes(data)
        simulator = Cosimulator(paths, folder)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    _STATE.update(digest=digest, simulator=simulator, folder=folder)
    if not _EXIT_HOOK:
        _EXIT_HOOK.append(atexit.register(close_worker_simulator))
    return simulator


def _run_on_worker(fmus: dict[str, bytes], applied) -> dict:
    """Task: simulate one applied case with this worker process's Cosimulator."""
    with _LOCK:
        return simulate(applied, _simulator(fmus))


def _reference_on_worker(fmus: dict[str, bytes], applied) -> tuple:
    """Task: the reference solution of one applied case, with this worker process's FMUs if it needs them."""
    with _LOCK:
        return compute_reference(applied, _simulator(fmus).paths)


def run_on_cluster(client: distributed.Client, tasks, fmu_paths: dict):
    """Submit the tasks (``(kind, tag, applied scenario)``) and yield ``(kind, tag, result)`` as
    they finish; closing the generator early cancels what has not finished. A task whose workers
    the scheduler lost too often (``KilledWorker``) yields ``lost_outcome`` for a run; a reference
    solution is computed in this process then."""
    client.register_plugin(CosimulatorCleanup())
    blobs = {name: Path(path).read_bytes() for name, path in fmu_paths.items()}
    [fmus] = client.scatter([blobs], broadcast=True)
    pending = {}
    for kind, tag, applied in tasks:
        task = _reference_on_worker if kind == "reference" else _run_on_worker
        future = client.submit(task, fmus, applied, pure=False)
        pending[future] = (kind, tag, applied)
    try:
        for future in distributed.as_completed(list(pending), loop=client.loop):
            kind, tag, applied = pending.pop(future)
            try:
                result = future.result()
            except distributed.KilledWorker as error:
                reason = f"Dask worker lost {error.allowed_failures + 1} times while running it (killed or crashed)"
                result = compute_reference(applied, fmu_paths) if kind == "reference" else lost_outcome(reason)
            future.release()
            yield kind, tag, result
    finally:
        if pending:
            client.cancel(list(pending))
