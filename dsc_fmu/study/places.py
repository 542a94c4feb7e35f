"""Where a sweep's tasks run locally: in this process, or on a pool of worker processes (one Cosimulator each)."""

from __future__ import annotations

import multiprocessing
import multiprocessing.util
import os
import signal
from collections import Counter, deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from ..cosim.master import Cosimulator
from .tasks import Task

__all__ = ["LOST_TWICE", "Losses", "Pool", "in_process"]

LOST_TWICE = "worker process lost twice (killed or crashed)"


class _Place:
    """A process where tasks run: the FMU files, and one Cosimulator made on first need in ``folder``."""

    def __init__(self, fmu_paths: dict, folder: Path):
        self.fmu_paths, self._folder, self._simulator = fmu_paths, folder, None

    def simulator(self) -> Cosimulator:
        if self._simulator is None:
            self._folder.mkdir(parents=True, exist_ok=True)
            self._simulator = Cosimulator(self.fmu_paths, self._folder)
        return self._simulator

    def compute(self, task: Task):
        return task.compute(self.fmu_paths, self.simulator)

    def close(self) -> None:
        if self._simulator is not None:
            self._simulator.close()


_WORKER: dict = {}


def _init_pool_worker(fmu_paths: dict, work: str) -> None:
    """Pool initializer: this worker's place, its Cosimulator to be made in ``work/<pid>``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops the pool
    _WORKER["place"] = place = _Place(fmu_paths, Path(work) / str(os.getpid()))
    multiprocessing.util.Finalize(None, place.close, exitpriority=10)  # workers exit without atexit


def _on_pool_worker(task: Task):
    return _WORKER["place"].compute(task)


def in_process(tasks, fmu_paths: dict, work: Path):
    """Run tasks here, one after the other, with one Cosimulator.

    Parameters
    ----------
    tasks : iterable of Task
        What to compute.
    fmu_paths : dict
        The FMU files by name.
    work : pathlib.Path
        Where the Cosimulator extracts them (in a folder named after this process), when a task needs it.

    Yields
    ------
    tuple
        ``(task, value)``, in the order of ``tasks``; closing early frees the Cosimulator.
    """
    place = _Place(fmu_paths, work / str(os.getpid()))
    try:
        for task in tasks:
            yield task, place.compute(task)
    finally:
        place.close()


def _executor(fmu_paths: dict, work: Path, jobs: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_pool_worker, initargs=(dict(fmu_paths), str(work)))


class Losses:
    """What running a sweep's tasks lost: nothing, where they run in this process or on a Dask cluster.

    Attributes
    ----------
    workers_lost : int
        How many times a process pool lost a worker (and broke).
    retried : int
        How many computations in flight were retried on a new pool.
    """

    workers_lost = 0
    retried = 0


class Pool(Losses):
    """Worker processes (spawned), each with its own Cosimulator, given at most one task each at a time.

    So the tasks in flight are those running on a worker. When a worker process is lost (killed or
    crashed: the pool breaks, and with it every task in flight), a new pool retries those tasks once;
    a task lost twice becomes ``task.lost(LOST_TWICE)``. ``workers_lost`` counts the broken pools,
    ``retried`` the retried tasks.

    Parameters
    ----------
    fmu_paths : dict
        The FMU files by name.
    work : pathlib.Path
        Where each worker's Cosimulator extracts them (in a folder named after its process).
    jobs : int
        How many worker processes.
    """

    def __init__(self, fmu_paths: dict, work: Path, jobs: int):
        self.fmu_paths, self.work, self.jobs = fmu_paths, work, jobs

    def run(self, tasks):
        """Compute tasks on the workers.

        Parameters
        ----------
        tasks : iterable of Task
            What to compute.

        Yields
        ------
        tuple
            ``(task, value)``, in the order they finish; closing early stops the workers at once.
        """
        queue, losses, in_flight, executor, finished = deque(tasks), Counter(), {}, None, False
        try:
            while queue or in_flight:
                if executor is None:
                    executor = _executor(self.fmu_paths, self.work, self.jobs)
                broken = self._submit(executor, queue, in_flight)
                if in_flight:
                    done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                    if any(isinstance(future.exception(), BrokenProcessPool) for future in done):
                        broken = True
                        done, _ = wait(in_flight)  # a broken pool fails every task in flight at once
                    retry = []
                    for future in done:
                        task = in_flight.pop(future)
                        if not isinstance(future.exception(), BrokenProcessPool):
                            yield task, future.result()  # a task's own error is raised here
                            continue
                        losses[task] += 1
                        if losses[task] == 1:
                            retry.append(task)
                        else:
                            yield task, task.lost(LOST_TWICE, self.fmu_paths)
                    queue.extendleft(reversed(retry))
                    self.retried += len(retry)
                if broken:
                    self.workers_lost += 1
                    executor.shutdown(wait=True, cancel_futures=True)
                    executor = None
            finished = True
        finally:
            if executor is not None:
                if not finished:  # interrupted or failed: stop the workers now rather than after their current runs
                    for process in list((getattr(executor, "_processes", None) or {}).values()):
                        process.terminate()
                executor.shutdown(wait=True, cancel_futures=True)

    def _submit(self, executor: ProcessPoolExecutor, queue: deque, in_flight: dict) -> bool:
        """Hand out tasks of ``queue`` until ``jobs`` are in flight; whether the pool broke meanwhile."""
        while queue and len(in_flight) < self.jobs:
            try:
                future = executor.submit(_on_pool_worker, queue[0])
            except BrokenProcessPool:
                return True
            in_flight[future] = queue.popleft()
        return False
