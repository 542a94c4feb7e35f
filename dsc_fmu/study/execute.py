"""Running a sweep's cases, cached: in this process, on a process pool or on a Dask cluster."""

from __future__ import annotations

import multiprocessing
import multiprocessing.util
import os
import re
import shutil
import signal
import tempfile
import warnings
from collections import Counter, defaultdict, deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ..cosim.master import Cosimulator
from ..cosim.progress import ProgressLine
from ..scenario import Scenario
from .cache import CacheEntryError, CacheWarning, SweepCache, case_key, fmu_identities, reference_key
from .cases import Case, Runner, SweepError, apply, check_scheduler
from .rows import Outcome, make_row
from .tasks import ReferenceSolution, Run, Task

__all__ = ["execute", "Execution", "WorkerLostWarning", "LOST_TWICE", "prepare_sweep_folder"]

LOST_TWICE = "worker process lost twice (killed or crashed)"
_WORK_FOLDER = re.compile(r"sweep-(\d+)-")


class WorkerLostWarning(UserWarning):
    """Worker processes of a sweep were lost (killed or crashed): what was in flight was retried."""


@dataclass(frozen=True)
class Execution:
    """What ``execute`` did; two executions add up (a sweep's grid and its refinement).

    Parameters
    ----------
    rows : list of dict
        The rows (``rows.ROW_KEYS``), in the order of the cases.
    cached : int, optional
        How many of them came from the cache.
    ran : int, optional
        How many were run now.
    lost : tuple of str, optional
        The keys of the runs that did not finish: their rows carry the reason, they are not cached.
    unverified : tuple of CacheEntryError, optional
        The cache entries that did not verify and were recomputed.
    workers_lost : int, optional
        How many times the process pool lost a worker.
    retried : int, optional
        How many computations in flight were retried on a new pool.
    """

    rows: list
    cached: int = 0
    ran: int = 0
    lost: tuple = ()
    unverified: tuple = ()
    workers_lost: int = 0
    retried: int = 0

    def __add__(self, other: Execution) -> Execution:
        """Two executions as one (a sweep's grid and its refinement): rows one after the other, counts added."""
        return Execution(self.rows + other.rows, self.cached + other.cached, self.ran + other.ran,
                         self.lost + other.lost, self.unverified + other.unverified,
                         self.workers_lost + other.workers_lost, self.retried + other.retried)

    def warn(self) -> None:
        """Warn of what went wrong, one line per kind of problem.

        One CacheWarning if cache entries did not verify, one WorkerLostWarning if a worker was lost
        or runs did not finish; nothing if all went well.
        """
        if self.unverified:
            count = len(self.unverified)
            what = "1 cache entry did not verify and was recomputed:" if count == 1 else \
                f"{count} cache entries did not verify and were recomputed; the first:"
            warnings.warn(f"{what} {self.unverified[0]}", CacheWarning, stacklevel=2)
        parts = []
        if self.workers_lost:
            times = "" if self.workers_lost == 1 else f" {self.workers_lost} times"
            parts.append(f"a worker process was lost (killed or crashed){times}; {self.retried} "
                         f"{'computation' if self.retried == 1 else 'computations'} in flight retried on a new pool")
        if self.lost:
            parts.append(f"{len(self.lost)} {'run' if len(self.lost) == 1 else 'runs'} did not finish: "
                         "rows with the reason, not cached")
        if parts:
            warnings.warn("; ".join(parts), WorkerLostWarning, stacklevel=2)


def prepare_sweep_folder(out_dir: Path) -> None:
    """Create the sweep folder if needed and check that files can be written in it.

    Parameters
    ----------
    out_dir : pathlib.Path
        The sweep folder.

    Raises
    ------
    SweepError
        One line naming ``out_dir``, if it cannot be created or written in.
    """
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


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _remove_stale_work(work_root: Path) -> None:
    """Remove the work folders ``sweep-<pid>-*`` in ``work_root`` whose sweep process is gone (killed
    before it could clean up), and ``work_root`` itself if nothing else is left in it."""
    for folder in work_root.glob("sweep-*"):
        match = _WORK_FOLDER.match(folder.name)
        if match and folder.is_dir() and not _alive(int(match[1])):
            shutil.rmtree(folder, ignore_errors=True)
    try:
        work_root.rmdir()
    except OSError:
        pass


# --- where the tasks run: this process, a process pool (one Cosimulator per worker), a Dask cluster ---


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


def _in_process(tasks, fmu_paths, work: Path):
    """Run the tasks here, one after the other, with one Cosimulator."""
    place = _Place(fmu_paths, work / str(os.getpid()))
    try:
        for task in tasks:
            yield task, place.compute(task)
    finally:
        place.close()


def _executor(fmu_paths: dict, work: Path, jobs: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_pool_worker, initargs=(dict(fmu_paths), str(work)))


def _pool(tasks, fmu_paths, work: Path, jobs: int, events: Counter):
    """Run the tasks on ``jobs`` worker processes (spawned), each with its own Cosimulator, handing
    out at most ``jobs`` at a time, so that the tasks in flight are those running on a worker.

    When a worker process is lost (killed or crashed: the pool breaks, and with it every task in
    flight), a new pool retries those tasks once; a task lost twice becomes ``task.lost(LOST_TWICE)``.
    ``events`` counts the broken pools (``workers_lost``) and the retried tasks (``retried``).
    """
    queue, losses, in_flight, executor, finished = deque(tasks), Counter(), {}, None, False
    try:
        while queue or in_flight:
            if executor is None:
                executor = _executor(fmu_paths, work, jobs)
            broken = False
            while queue and len(in_flight) < jobs and not broken:
                try:
                    future = executor.submit(_on_pool_worker, queue[0])
                except BrokenProcessPool:
                    broken = True
                else:
                    in_flight[future] = queue.popleft()
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
                        yield task, task.lost(LOST_TWICE, fmu_paths)
                queue.extendleft(reversed(retry))
                events["retried"] += len(retry)
            if broken:
                events["workers_lost"] += 1
                executor.shutdown(wait=True, cancel_futures=True)
                executor = None
        finished = True
    finally:
        if executor is not None:
            if not finished:  # interrupted or failed: stop the workers now rather than after their current runs
                for process in list((getattr(executor, "_processes", None) or {}).values()):
                    process.terminate()
            executor.shutdown(wait=True, cancel_futures=True)


def execute(scenario: Scenario, cases: list[Case], out_dir: Path | str, fmu_paths: dict, runner: Runner = Runner(), *,
            warn: bool = True) -> Execution:
    """Run every case not yet cached in ``out_dir`` and return the rows of all.

    Locally (no ``runner.scheduler``), ``runner.jobs`` worker processes each load the FMUs once (into
    ``out_dir/.work``, removed at the end whatever happens; the work folders of sweeps killed before
    they could remove theirs are removed at the start). A worker process lost (killed or crashed)
    costs the runs in flight one retry on a new pool; a run lost twice is a row with the reason
    ``LOST_TWICE``, not cached. With a scheduler the runs go to that Dask cluster instead. Each
    finished run is cached at once (``cache``), so an interrupted sweep resumes where it stopped;
    cached cases are not run again. Reference solutions are computed once per physical case and
    cached too. Cache entries that do not verify (damaged, edited, of an older layout) are
    recomputed, references included.

    Parameters
    ----------
    scenario : Scenario
        The sweep's scenario.
    cases : list of Case
        The cases to run on it (``build_cases``).
    out_dir : pathlib.Path or str
        The sweep folder: its cache, and the work folder while it runs.
    fmu_paths : dict
        The FMU files by name (``ensure_fmus``).
    runner : Runner, optional
        Where the runs go and whether a progress bar shows. Default ``Runner()``: all cores.
    warn : bool, optional
        Issue ``Execution.warn`` (one line per kind of problem) before returning. Default True.

    Returns
    -------
    Execution
        The rows of all cases, in the order of ``cases``, and what was done.

    Raises
    ------
    SweepError
        One line, if the scheduler cannot be reached within ``runner.scheduler_timeout`` s (nothing
        is written then) or ``out_dir`` cannot be a folder.
    """
    out_dir, cache = Path(out_dir), SweepCache(out_dir)
    identities = fmu_identities(fmu_paths)
    plans = [(case, apply(scenario, case), case_key(scenario, case, identities),
              reference_key(scenario, case, identities)) for case in cases]
    done, todo, unverified = {}, {}, []
    for case, applied, key, ref_key in plans:
        if key in done or key in todo:
            continue
        cached, _ = _verified(cache.row, key, unverified)
        if cached is not None:
            done[key] = {**cached, "scenario": scenario.name}
        else:
            todo[key] = (case, applied, ref_key)
    from_cache = set(done)
    references, missing = _references(cache, plans, todo, unverified)
    events = Counter()
    if (todo or missing) and runner.scheduler is not None:
        check_scheduler(runner.scheduler, runner.scheduler_timeout)  # before anything is written
    prepare_sweep_folder(out_dir)
    _remove_stale_work(out_dir / ".work")
    lost = []
    if todo or missing:
        tasks = [ReferenceSolution(k, applied) for k, applied in missing.items()]
        runs = sorted(todo, key=lambda k: -todo[k][1].simulation.stop_time / todo[k][1].simulation.step_size)
        tasks += [Run(key, todo[key][1]) for key in runs]  # the longest first, for an even load
        with _results(tasks, out_dir, fmu_paths, runner, events) as results:
            done.update(_collect(scenario, todo, references, cache, identities, results, runner.progress, lost))
    keys = [key for _, _, key, _ in plans]
    execution = Execution([done[key] for key in keys], cached=sum(key in from_cache for key in keys),
                          ran=sum(key not in from_cache for key in keys), lost=tuple(lost),
                          unverified=tuple(unverified), workers_lost=events["workers_lost"], retried=events["retried"])
    if warn:
        execution.warn()
    return execution


def _references(cache: SweepCache, plans, todo: dict, unverified: list) -> tuple[dict, dict]:
    """The verified cached reference solutions the runs of ``todo`` need (by key), and the reference
    solutions to compute (key: applied scenario): those the runs need and are not cached, and every
    one of ``plans`` cached but not verifying (appended to ``unverified``)."""
    needed = {ref_key for _, _, ref_key in todo.values()}
    references, missing, seen = {}, {}, set()
    for _, applied, _, ref_key in plans:
        if ref_key in seen:
            continue
        seen.add(ref_key)
        reference, verified = _verified(cache.reference, ref_key, unverified)
        if reference is not None and ref_key in needed:
            references[ref_key] = reference
        elif not verified or ref_key in needed:
            missing[ref_key] = applied
    return references, missing


def _verified(read, key: str, unverified: list) -> tuple:
    """``read(key)`` from the cache (None: not cached) and whether the entry verified; one that does
    not is appended to ``unverified`` and counts as not cached."""
    try:
        return read(key), True
    except CacheEntryError as error:
        unverified.append(error)
        return None, False


@contextmanager
def _results(tasks: list[Task], out_dir: Path, fmu_paths: dict, runner: Runner, events: Counter):
    """The results of ``tasks`` as ``(task, value)`` as they finish, from this process, a process pool
    or a Dask cluster; on leaving, stop what still runs and remove the work folder."""
    if runner.scheduler is not None:
        from .cluster import connect, run_on_cluster

        client = connect(runner.scheduler, runner.scheduler_timeout)
        results = run_on_cluster(client, tasks, fmu_paths)
        try:
            yield results
        finally:
            try:
                results.close()  # cancels the cluster's remaining tasks
            finally:
                client.close()
        return
    try:
        (out_dir / ".work").mkdir(exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f"sweep-{os.getpid()}-", dir=out_dir / ".work"))
    except OSError as error:
        raise _folder_error(out_dir, error) from None
    try:
        jobs = (os.cpu_count() or 1) if runner.jobs is None else runner.jobs
        workers = min(jobs, sum(task.needs_simulator for task in tasks))
        if workers <= 1:
            results = _in_process(tasks, fmu_paths, work)
        else:
            results = _pool(tasks, fmu_paths, work, workers, events)
        try:
            yield results
        finally:
            results.close()  # stops the pool (at once if it did not finish) or frees this process's Cosimulator
    finally:
        shutil.rmtree(work, ignore_errors=True)
        try:
            work.parent.rmdir()  # .work itself, unless another sweep is using it
        except OSError:
            pass


class _Collector:
    """The rows (by key) of the runs of ``todo`` (key: (case, applied scenario, reference key)) as
    their outcomes and reference solutions come in (``Task.hand_over``), each cached as soon as both
    are in, except the runs that did not finish (their keys are appended to ``lost``) and, under the
    "local" stability, those whose reference solution failed (judged as settled runs for now)."""

    def __init__(self, scenario: Scenario, todo: dict, references: dict, cache: SweepCache, identities: dict,
                 bar: ProgressLine, lost: list):
        self.rows, self._waiting = {}, defaultdict(list)
        self._remaining = Counter(ref_key for _, _, ref_key in todo.values())
        self._local = scenario.simulation.stability.from_start
        self._todo, self._references, self._cache, self._identities = todo, references, cache, identities
        self._bar, self._lost = bar, lost

    def take_reference(self, ref_key: str, value: tuple) -> None:
        reference, why = value
        if reference is None:
            judged = "; they are judged as settled runs and not cached" if self._local else ""
            warnings.warn(f"reference solution failed ({why}): deviations are NaN for its runs{judged}",
                          stacklevel=6)  # the caller of execute's caller
        else:
            self._cache.store_reference(ref_key, reference)
        if self._remaining[ref_key]:
            self._references[ref_key] = reference
        for key, outcome in self._waiting.pop(ref_key, []):
            self._finish(key, outcome)

    def take_run(self, key: str, outcome: Outcome) -> None:
        ref_key = self._todo[key][2]
        if ref_key in self._references:
            self._finish(key, outcome)
        else:
            self._waiting[ref_key].append((key, outcome))

    def _finish(self, key: str, outcome: Outcome) -> None:
        case, applied, ref_key = self._todo[key]
        reference = self._references[ref_key]
        self.rows[key] = make_row(applied, case, (key, ref_key), outcome, reference)
        if outcome.lost:
            self._lost.append(key)
        elif reference is not None or not self._local:  # judged without its reference: not for keeps
            self._cache.store_run(key, self.rows[key], outcome.trajectory, self._identities)
        self._bar.update()
        self._remaining[ref_key] -= 1
        if not self._remaining[ref_key]:
            self._references.pop(ref_key)  # no run left that needs it


def _collect(scenario: Scenario, todo: dict, references: dict, cache: SweepCache, identities: dict, results,
             progress: bool, lost: list) -> dict:
    """Rows (by key) of the runs of ``todo`` from ``results`` (``_Collector``)."""
    with ProgressLine(len(todo), f"sweep {scenario.name}", "runs", quiet=not progress) as bar:
        collector = _Collector(scenario, todo, references, cache, identities, bar, lost)
        for task, value in results:
            task.hand_over(value, collector)
    return collector.rows
