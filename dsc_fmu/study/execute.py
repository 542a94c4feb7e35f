"""Running a sweep's cases, cached, through a ``concurrent.futures`` executor: a process pool or a Dask cluster
(docs/step-size-studies.md)."""

from __future__ import annotations

import functools
import math
import multiprocessing
import multiprocessing.util
import os
import re
import shutil
import signal
import tempfile
import threading
import warnings
from collections import Counter, deque
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable, NamedTuple

import psutil

from ..cosim.master import Cosimulator
from ..cosim.progress import ProgressLine
from ..scenario import Scenario
from .cache import CacheEntryError, CacheWarning, SweepCache, fmu_identities
from .cases import Case, Runner, SweepError, check_scheduler
from .rows import Outcome, Plan, ReferenceOutcome, compute_reference, make_row, simulate

__all__ = ["WorkerLostWarning", "LOST_TWICE"]

LOST_TWICE = "worker process lost twice (killed or crashed)"
_WORK_FOLDER = re.compile(r"sweep-(\d+)-")


class WorkerLostWarning(UserWarning):
    """Worker processes of a sweep were lost (killed or crashed): what was in flight was retried."""


@dataclass(frozen=True)
class Execution:
    """What running cases did: their ``rows`` in the order of the cases, how many came from the cache and how
    many ran, the keys of the runs ``lost`` (rows with the reason, not cached), the ``unverified`` cache
    entries (``CacheEntryError``) recomputed, the pools broken and the computations retried. Two add up."""

    rows: list
    cached: int = 0
    ran: int = 0
    lost: tuple = ()
    unverified: tuple = ()
    workers_lost: int = 0
    retried: int = 0

    def __add__(self, other: Execution) -> Execution:
        return Execution(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    def warn(self) -> None:
        """One CacheWarning if entries did not verify, one WorkerLostWarning if workers or runs were lost."""
        if self.unverified:
            what = "1 cache entry did not verify and was recomputed:" if len(self.unverified) == 1 else \
                f"{len(self.unverified)} cache entries did not verify and were recomputed; the first:"
            warnings.warn(f"{what} {self.unverified[0]}", CacheWarning, stacklevel=2)
        times = "" if self.workers_lost == 1 else f" {self.workers_lost} times"
        parts = [f"a worker process was lost (killed or crashed){times}; {_count(self.retried, 'computation')} in "
                 "flight retried on a new pool"] if self.workers_lost else []
        parts += [f"{_count(len(self.lost), 'run')} did not finish: rows with the reason, not cached"] * bool(self.lost)
        if parts:
            warnings.warn("; ".join(parts), WorkerLostWarning, stacklevel=2)


def _count(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def prepare_sweep(out_dir: Path, runner: Runner) -> None:
    """SweepError (one line) unless the scheduler (if any) answers and ``out_dir`` is made and can be
    written in; nothing is written if the scheduler cannot be reached."""
    if runner.scheduler is not None:
        check_scheduler(runner.scheduler, runner.scheduler_timeout)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out_dir):
            pass
    except OSError as error:
        raise _folder_error(out_dir, error) from None


def _folder_error(out_dir: Path, error: OSError) -> SweepError:
    """The SweepError of a sweep folder the system refuses: named as given, whatever file inside failed."""
    existing = next((path for path in (out_dir, *out_dir.parents) if path.exists()), None)
    if existing is not None and not existing.is_dir():
        reason = "it is not a folder" if existing == out_dir else f"{existing} is not a folder"
    else:
        text = error.strerror or type(error).__name__
        reason = text[:1].lower() + text[1:]
    return SweepError(f"{out_dir}: cannot use as the sweep folder: {reason}; "
                      "allowed: a writable folder, or a path where one can be created")


def _remove_work(work_root: Path, folder: Path | None = None) -> None:
    """Remove ``folder`` and the work folders ``sweep-<pid>-*`` whose sweep process is gone (killed before
    it could clean up), and ``work_root`` itself if nothing else is left in it."""
    for found in work_root.glob("sweep-*"):
        match = _WORK_FOLDER.match(found.name)
        if found == folder or match and found.is_dir() and not psutil.pid_exists(int(match[1])):
            shutil.rmtree(found, ignore_errors=True)
    try:
        work_root.rmdir()
    except OSError:
        pass


class _Fmus:
    """A process's FMU files and their Cosimulator, made in ``folder`` on first need; one computation at a time."""

    def __init__(self, paths: dict, folder: Path):
        self.paths, self.folder, self.lock, self._cosimulator = paths, folder, threading.Lock(), None

    def compute(self, fn: Callable, applied: Scenario):
        with self.lock:
            return fn(self, applied)

    def simulate(self, applied: Scenario) -> Outcome:
        if self._cosimulator is None:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._cosimulator = Cosimulator(self.paths, self.folder)
        return simulate(applied, self._cosimulator)

    def reference(self, applied: Scenario) -> ReferenceOutcome:
        return compute_reference(applied, self.paths)

    def close(self) -> None:
        with self.lock:  # after the computation in progress, if any
            try:
                if self._cosimulator is not None:
                    self._cosimulator.close()
            finally:
                shutil.rmtree(self.folder, ignore_errors=True)


_POOL_WORKER: dict = {}


def _start_pool_worker(fmu_paths: dict, work: str) -> None:
    """Pool initializer: this worker's FMUs, loaded on first need into ``work/<pid>``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops the pool
    _POOL_WORKER["fmus"] = fmus = _Fmus(fmu_paths, Path(work) / str(os.getpid()))
    multiprocessing.util.Finalize(None, fmus.close, exitpriority=10)  # workers exit without atexit


def _on_pool_worker(fn: Callable, applied: Scenario):
    return _POOL_WORKER["fmus"].compute(fn, applied)


class _InProcess(Executor):
    """Runs each call when it is submitted, in this process."""

    def submit(self, fn, /, *args):
        future = Future()
        try:
            future.set_result(fn(*args))
        except Exception as error:
            future.set_exception(error)
        return future


class _Call(NamedTuple):
    fn: Callable  # _Fmus.simulate or _Fmus.reference, of the process it runs in
    key: str
    applied: Scenario
    retried: bool = False


class _Lost(NamedTuple):
    reason: str


class Workers:
    """Where a sweep's computations run, from the first that needs them until the sweep ends
    (docs/step-size-studies.md): ``min(runner.jobs, runs)`` spawned processes of a ``ProcessPoolExecutor``
    (one: this process), each with the FMUs in its own folder of ``out_dir/.work``, one computation at a
    time; or with ``runner.scheduler`` a Dask client's executor, the FMUs on every worker
    (``cluster.FmusOnWorkers``). A broken pool costs the computations in flight one retry on a new one
    (a run lost twice is a row with ``LOST_TWICE``); a run Dask lost too often is a row with the reason.
    Leaving the ``with`` block stops what still runs (at once after an error or Ctrl-C) and removes the
    work folder, and those of sweeps killed before they could.
    """

    def __init__(self, out_dir: Path | str, fmu_paths: dict, runner: Runner = Runner()):
        self.out_dir, self.fmu_paths, self.runner = Path(out_dir), fmu_paths, runner
        self.cache, self.identities = SweepCache(out_dir), fmu_identities(fmu_paths)
        self.workers_lost = self.retried = 0
        self._executor = self._client = self._work = self._here = None

    def __enter__(self) -> Workers:
        _remove_work(self.out_dir / ".work")
        return self

    def __exit__(self, kind, *exc) -> None:
        try:
            if self._client is not None:
                try:
                    self._client.unregister_worker_plugin(self._plugin)
                except Exception:  # noqa: BLE001 - leaving on an error: that one is the one to show
                    if kind is None:
                        raise
                finally:
                    self._client.close()
            elif self._executor is not None:
                if kind is not None:  # stop the workers now rather than after their current runs
                    for process in list((getattr(self._executor, "_processes", None) or {}).values()):
                        process.terminate()
                self._executor.shutdown(wait=True, cancel_futures=True)
        finally:
            if self._here is not None:
                self._here.close()
            if self._work is not None:
                _remove_work(self._work.parent, self._work)

    def _start(self, size: int) -> None:
        """The executor: of a Dask client, of ``size`` worker processes, or (``size`` 1) of this process."""
        if self.runner.scheduler is not None:
            from distributed import KilledWorker

            from .cluster import FmusOnWorkers, connect, on_worker

            self._client = connect(self.runner.scheduler, self.runner.scheduler_timeout)
            plugin = FmusOnWorkers(self.fmu_paths, _Fmus)
            self._client.register_plugin(plugin)
            self._plugin, self._task = plugin.name, functools.partial(on_worker, plugin.name)
            self._executor, self._size, self._lost = self._client.get_executor(pure=False), math.inf, KilledWorker
            return
        if self._work is None:
            try:
                (self.out_dir / ".work").mkdir(exist_ok=True)
                self._work = Path(tempfile.mkdtemp(prefix=f"sweep-{os.getpid()}-", dir=self.out_dir / ".work"))
            except OSError as error:
                raise _folder_error(self.out_dir, error) from None
        self._size, self._lost = size, BrokenProcessPool
        if size == 1:
            self._here, self._executor = _Fmus(self.fmu_paths, self._work / str(os.getpid())), _InProcess()
            self._task = self._here.compute
        else:
            self._executor = ProcessPoolExecutor(size, mp_context=multiprocessing.get_context("spawn"),
                                                 initializer=_start_pool_worker,
                                                 initargs=(dict(self.fmu_paths), str(self._work)))
            self._task = _on_pool_worker

    def _results(self, calls: list[_Call], runs: int):
        """``(call, value)`` as the calls finish; ``_Lost`` the value of a call whose workers were lost. At most
        one call per worker is in flight: a broken pool fails those, and only those are retried."""
        if self._executor is None:
            jobs = (os.cpu_count() or 1) if self.runner.jobs is None else self.runner.jobs
            self._start(max(1, min(jobs, runs)))
        queue, in_flight = deque(calls), {}
        try:
            while queue or in_flight:
                broken = False
                try:
                    while queue and len(in_flight) < self._size:
                        in_flight[self._executor.submit(self._task, queue[0].fn, queue[0].applied)] = queue[0]
                        queue.popleft()
                except BrokenProcessPool:
                    broken = True
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                if broken or any(isinstance(future.exception(), BrokenProcessPool) for future in done):
                    broken, (done, _) = True, wait(in_flight)  # a broken pool fails every call in flight
                for future in done:
                    call, error = in_flight.pop(future), future.exception()
                    if isinstance(error, BrokenProcessPool) and not call.retried:
                        queue.appendleft(call._replace(retried=True))
                        self.retried += 1
                    elif isinstance(error, self._lost):
                        yield call, _Lost(LOST_TWICE if isinstance(error, BrokenProcessPool) else
                                          f"Dask worker lost {error.allowed_failures + 1} times while running it "
                                          "(killed or crashed)")
                    else:
                        yield call, future.result()
                if broken:
                    self.workers_lost += 1
                    self._executor.shutdown(wait=True, cancel_futures=True)
                    self._start(self._size)
        finally:
            for future in in_flight:
                future.cancel()

    def execute(self, scenario: Scenario, cases: list[Case], progress: bool = True) -> Execution:
        """Run every case not yet cached and return the rows of all, in the order of ``cases``.

        A run's row is made and cached as soon as the run and its reference solution (one per physical
        case, cached too) are in; entries that do not verify are recomputed. Under the "local" stability,
        a run whose reference solution failed is judged as a settled one and not cached.
        """
        plans, unverified = [Plan.of(scenario, case, self.identities) for case in cases], []

        def read(entry: Callable, key: str):
            try:
                return entry(key)
            except CacheEntryError as error:
                unverified.append(error)

        rows, todo, first = {}, {}, {}
        for plan in plans:
            first.setdefault(plan.reference_key, plan.applied)
            if plan.key not in rows and plan.key not in todo:
                cached = read(self.cache.row, plan.key)
                if cached is None:
                    todo[plan.key] = plan
                else:
                    rows[plan.key] = {**cached, "scenario": scenario.name}
        needs = Counter(plan.reference_key for plan in todo.values())  # the runs to do that need each reference
        references, calls = {}, []
        for key, applied in first.items():
            damaged = len(unverified)
            reference = read(self.cache.reference, key)
            if reference is not None and needs[key]:
                references[key] = reference
            elif len(unverified) > damaged or needs[key]:
                calls.append(_Call(_Fmus.reference, key, applied))
        runs = sorted(todo.values(), key=lambda plan: -plan.applied.simulation.stop_time
                      / plan.applied.simulation.step_size)  # the longest first, for an even load
        calls += [_Call(_Fmus.simulate, plan.key, plan.applied) for plan in runs]
        lost, notes, waiting, before = [], [], {}, (self.workers_lost, self.retried)
        local = scenario.simulation.stability.from_start
        with ProgressLine(len(todo), f"sweep {scenario.name}", "runs",
                          quiet=not (progress and self.runner.progress)) as bar:
            for call, value in self._results(calls, len(runs)) if calls else ():
                if call.fn is _Fmus.reference:
                    value = compute_reference(call.applied, self.fmu_paths) if isinstance(value, _Lost) else value
                    if value.solution is None:
                        judged = "; they are judged as settled runs and not cached" if local else ""
                        notes.append(f"reference solution failed ({value.failure}): deviations are NaN for its "
                                     f"runs{judged}")
                    else:
                        self.cache.store_reference(call.key, value.solution)
                    if needs[call.key]:
                        references[call.key] = value.solution
                    ready = waiting.pop(call.key, [])
                else:
                    ready = [(todo[call.key], Outcome.of_lost(value.reason) if isinstance(value, _Lost) else value)]
                    if ready[0][0].reference_key not in references:
                        waiting.setdefault(ready[0][0].reference_key, []).extend(ready)
                        continue
                for plan, outcome in ready:
                    reference = references[plan.reference_key]
                    rows[plan.key] = make_row(plan, outcome, reference)
                    if outcome.lost:
                        lost.append(plan.key)
                    elif reference is not None or not local:  # judged without its reference: not for keeps
                        self.cache.store_run(plan.key, rows[plan.key], outcome.trajectory, self.identities)
                    bar.update()
                    needs[plan.reference_key] -= 1
                    if not needs[plan.reference_key]:
                        references.pop(plan.reference_key)  # no run left that needs it
        for note in notes:
            warnings.warn(note, stacklevel=3)
        ran = sum(plan.key in todo for plan in plans)
        return Execution([rows[plan.key] for plan in plans], len(plans) - ran, ran, tuple(lost), tuple(unverified),
                         self.workers_lost - before[0], self.retried - before[1])


def execute(scenario: Scenario, cases: list[Case], out_dir: Path | str, fmu_paths: dict, runner: Runner = Runner(),
            *, warn: bool = True) -> Execution:
    """``Workers.execute`` in the sweep folder ``out_dir`` (checked first, as a sweep checks it), then (``warn``)
    ``Execution.warn``. SweepError (one line) if the scheduler cannot be reached or ``out_dir`` cannot be a folder."""
    prepare_sweep(Path(out_dir), runner)
    with Workers(out_dir, fmu_paths, runner) as workers:
        done = workers.execute(scenario, cases)
    if warn:
        done.warn()
    return done
