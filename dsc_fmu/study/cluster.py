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
from .tasks import Task

__all__ = ["connect", "run_on_cluster", "CosimulatorCleanup", "close_worker_simulator", "worker_status"]

_STATE: dict = {"digest": None, "simulator": None, "folder": None}
_LOCK = threading.Lock()
_EXIT_HOOK = []


async def _identity(address: str) -> dict:
    async with distributed.rpc(address, connection_args=distributed.Security().get_connection_args("client")) as peer:
        return await peer.identity()


def connect(address: str, timeout: float) -> distributed.Client:
    """A client of the Dask scheduler at ``address``, checked first.

    Parameters
    ----------
    address : str
        The scheduler's address (``cases.parse_scheduler``).
    timeout : float
        How long to wait for the scheduler to answer, in s.

    Returns
    -------
    distributed.Client
        A client of it, not set as the default client.

    Raises
    ------
    SweepError
        One line, if ``address`` is not an address, cannot be reached, or what listens there does not
        answer as a Dask scheduler within ``timeout`` (a ``distributed.Client`` of such a server
        waits forever).
    """
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
    """This process's Cosimulator, for ``client.run(worker_status)``.

    Returns
    -------
    dict
        ``{"folder": its folder as text, None if there is none; "runs": how many runs it made}``.
    """
    simulator, folder = _STATE["simulator"], _STATE["folder"]
    return {"folder": None if folder is None else str(folder), "runs": 0 if simulator is None else simulator.runs}


class CosimulatorCleanup(WorkerPlugin):
    """Worker plugin: when the worker closes, free its Cosimulator and remove its folder.

    Register it with ``client.register_plugin(CosimulatorCleanup())``; ``run_on_cluster`` does.
    """

    name = "dsc-fmu-cosimulator-cleanup"
    idempotent = True

    def teardown(self, worker) -> None:
        """Free the worker's Cosimulator and remove its folder (``close_worker_simulator``).

        Parameters
        ----------
        worker : distributed.Worker
            The worker that closes.
        """
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


def _on_worker(fmus: dict[str, bytes], task: Task):
    """Dask task: compute ``task`` with this worker process's FMUs and Cosimulator."""
    with _LOCK:
        simulator = _simulator(fmus)
        return task.compute(simulator.paths, lambda: simulator)


def run_on_cluster(client: distributed.Client, tasks: list[Task], fmu_paths: dict):
    """Compute tasks on a Dask cluster and yield their values as they finish.

    Closing the generator early cancels what has not finished. A task whose workers the scheduler
    lost too often (``KilledWorker``) yields ``task.lost`` instead, computed in this process.

    Parameters
    ----------
    client : distributed.Client
        A client of the cluster's scheduler (``connect``).
    tasks : list of Task
        What to compute.
    fmu_paths : dict
        The FMU files by name: shipped once to every worker, and used here for a lost task.

    Yields
    ------
    tuple
        ``(task, value)``, in the order they finish.
    """
    client.register_plugin(CosimulatorCleanup())
    blobs = {name: Path(path).read_bytes() for name, path in fmu_paths.items()}
    [fmus] = client.scatter([blobs], broadcast=True)
    pending = {client.submit(_on_worker, fmus, task, pure=False): task for task in tasks}
    try:
        for future in distributed.as_completed(list(pending), loop=client.loop):
            task = pending.pop(future)
            try:
                value = future.result()
            except distributed.KilledWorker as error:
                value = task.lost(f"Dask worker lost {error.allowed_failures + 1} times while running it "
                                  "(killed or crashed)", fmu_paths)
            future.release()
            yield task, value
    finally:
        if pending:
            client.cancel(list(pending))
