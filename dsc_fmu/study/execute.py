"""Running a sweep's cases, cached: in this process, on a process pool or on a Dask cluster."""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import warnings
from collections import Counter, defaultdict
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ..cosim.progress import ProgressLine
from ..scenario import Scenario
from .cache import CacheEntryError, CacheWarning, SweepCache, fmu_identities
from .cases import Case, Runner, SweepError, check_scheduler
from .places import LOST_TWICE, Losses, Pool, in_process
from .plan import Plan
from .rows import Outcome, ReferenceOutcome, make_row
from .tasks import ReferenceSolution, Run, Task

__all__ = ["execute", "Execution", "WorkerLostWarning", "LOST_TWICE", "prepare_sweep"]

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


def prepare_sweep(out_dir: Path, runner: Runner) -> None:
    """Check that a sweep can start: its scheduler (if any) answers, its folder is made and can be written in.

    Nothing is written if the scheduler cannot be reached.

    Parameters
    ----------
    out_dir : pathlib.Path
        The sweep folder, created if missing.
    runner : Runner
        Where the runs go; with a scheduler, that it accepts a connection within ``runner.scheduler_timeout``.

    Raises
    ------
    SweepError
        One line, if the scheduler cannot be reached or ``out_dir`` cannot be created or written in.
    """
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


@dataclass(frozen=True)
class _Found:
    """What the cache holds for a sweep's plans.

    ``rows``: the cached rows by key; ``todo``: the plans to run, by key; ``references``: the cached
    reference solutions those need, by reference key; ``missing``: the reference solutions to compute
    (reference key: applied scenario), those the runs need and are not cached and every one cached but
    not verifying; ``unverified``: the entries that did not verify.
    """

    rows: dict
    todo: dict
    references: dict
    missing: dict
    unverified: tuple

    @property
    def work(self) -> bool:
        return bool(self.todo or self.missing)


def execute(scenario: Scenario, cases: list[Case], out_dir: Path | str, fmu_paths: dict, runner: Runner = Runner(), *,
            warn: bool = True, prepared: bool = False) -> Execution:
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
        Where the runs go and whether a progress line shows on a terminal. Default ``Runner()``: all cores.
    warn : bool, optional
        Issue ``Execution.warn`` (one line per kind of problem) before returning. Default True.
    prepared : bool, optional
        ``prepare_sweep`` checked ``out_dir`` and the runner's scheduler already (``run_sweep`` does,
        once for all its executions). Default False: checked here, before anything runs.

    Returns
    -------
    Execution
        The rows of all cases, in the order of ``cases``, and what was done.

    Raises
    ------
    SweepError
        One line, if the scheduler cannot be reached within ``runner.scheduler_timeout`` s (nothing
        is written then) or ``out_dir`` cannot be a folder (``prepare_sweep``).
    """
    out_dir, cache = Path(out_dir), SweepCache(out_dir)
    identities = fmu_identities(fmu_paths)
    plans = [Plan.of(scenario, case, identities) for case in cases]
    found = _look_up(cache, plans, scenario.name)
    if not prepared:
        prepare_sweep(out_dir, runner)
    _remove_stale_work(out_dir / ".work")
    rows, lost, losses = dict(found.rows), (), Losses()
    if found.work:
        tasks = [ReferenceSolution(key, applied) for key, applied in found.missing.items()]
        runs = sorted(found.todo.values(), key=lambda plan: -plan.applied.simulation.stop_time
                      / plan.applied.simulation.step_size)
        tasks += [Run(plan.key, plan.applied) for plan in runs]  # the longest first, for an even load
        with _results(tasks, out_dir, fmu_paths, runner) as (results, losses):
            collector = _collect(scenario, found, cache, identities, results, runner.progress)
        rows.update(collector.rows)
        lost = tuple(collector.lost)
    keys = [plan.key for plan in plans]
    execution = Execution([rows[key] for key in keys], cached=sum(key in found.rows for key in keys),
                          ran=sum(key not in found.rows for key in keys), lost=lost, unverified=found.unverified,
                          workers_lost=losses.workers_lost, retried=losses.retried)
    if warn:
        execution.warn()
    return execution


def _read(read, key: str) -> tuple:
    """``read(key)`` from the cache (None: not cached) and the CacheEntryError of an entry that does
    not verify (then it counts as not cached), else None."""
    try:
        return read(key), None
    except CacheEntryError as error:
        return None, error


def _look_up(cache: SweepCache, plans: list[Plan], name: str) -> _Found:
    """What ``cache`` holds for ``plans`` (the rows named for the scenario ``name``) and what is left to compute."""
    rows, todo, unverified = {}, {}, []
    for plan in plans:
        if plan.key in rows or plan.key in todo:
            continue
        cached, error = _read(cache.row, plan.key)
        unverified += [error] if error else []
        if cached is not None:
            rows[plan.key] = {**cached, "scenario": name}
        else:
            todo[plan.key] = plan
    needed, first = {plan.reference_key for plan in todo.values()}, {}
    for plan in plans:
        first.setdefault(plan.reference_key, plan.applied)
    references, missing = {}, {}
    for ref_key, applied in first.items():
        reference, error = _read(cache.reference, ref_key)
        unverified += [error] if error else []
        if reference is not None and ref_key in needed:
            references[ref_key] = reference
        elif error or ref_key in needed:
            missing[ref_key] = applied
    return _Found(rows, todo, references, missing, tuple(unverified))


@contextmanager
def _results(tasks: list[Task], out_dir: Path, fmu_paths: dict, runner: Runner):
    """The results of ``tasks`` as ``(task, value)`` as they finish, from this process, a process pool
    or a Dask cluster, and what running them lost (``places.Losses``); on leaving, stop what still runs and
    remove the work folder."""
    if runner.scheduler is not None:
        from .cluster import connect, run_on_cluster

        client = connect(runner.scheduler, runner.scheduler_timeout)
        results = run_on_cluster(client, tasks, fmu_paths)
        try:
            yield results, Losses()
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
        losses = Losses() if workers <= 1 else Pool(fmu_paths, work, workers)
        results = in_process(tasks, fmu_paths, work) if workers <= 1 else losses.run(tasks)
        try:
            yield results, losses
        finally:
            results.close()  # stops the pool (at once if it did not finish) or frees this process's Cosimulator
    finally:
        shutil.rmtree(work, ignore_errors=True)
        try:
            work.parent.rmdir()  # .work itself, unless another sweep is using it
        except OSError:
            pass


class _Collector:
    """The rows (by key) of the runs of ``found.todo`` as their outcomes and reference solutions come in
    (``Task.hand_over``), each cached as soon as both are in, except the runs that did not finish
    (their keys are kept in ``lost``) and, under the "local" stability, those whose reference solution
    failed (judged as settled runs for now); what a failed reference solution means is kept in
    ``warnings``, for after the progress line."""

    def __init__(self, scenario: Scenario, found: _Found, cache: SweepCache, identities: dict, bar: ProgressLine):
        self.rows, self.lost, self.warnings, self._waiting = {}, [], [], defaultdict(list)
        self._remaining = Counter(plan.reference_key for plan in found.todo.values())
        self._local = scenario.simulation.stability.from_start
        self._todo, self._references = found.todo, dict(found.references)
        self._cache, self._identities, self._bar = cache, identities, bar

    def take_reference(self, ref_key: str, value: ReferenceOutcome) -> None:
        if value.solution is None:
            judged = "; they are judged as settled runs and not cached" if self._local else ""
            self.warnings.append(f"reference solution failed ({value.failure}): deviations are NaN for its "
                                 f"runs{judged}")
        else:
            self._cache.store_reference(ref_key, value.solution)
        if self._remaining[ref_key]:
            self._references[ref_key] = value.solution
        for key, outcome in self._waiting.pop(ref_key, []):
            self._finish(key, outcome)

    def take_run(self, key: str, outcome: Outcome) -> None:
        ref_key = self._todo[key].reference_key
        if ref_key in self._references:
            self._finish(key, outcome)
        else:
            self._waiting[ref_key].append((key, outcome))

    def _finish(self, key: str, outcome: Outcome) -> None:
        plan = self._todo[key]
        reference = self._references[plan.reference_key]
        self.rows[key] = make_row(plan, outcome, reference)
        if outcome.lost:
            self.lost.append(key)
        elif reference is not None or not self._local:  # judged without its reference: not for keeps
            self._cache.store_run(key, self.rows[key], outcome.trajectory, self._identities)
        self._bar.update()
        self._remaining[plan.reference_key] -= 1
        if not self._remaining[plan.reference_key]:
            self._references.pop(plan.reference_key)  # no run left that needs it


def _collect(scenario: Scenario, found: _Found, cache: SweepCache, identities: dict, results,
             progress: bool) -> _Collector:
    """The rows (by key) and the lost runs of ``found.todo`` from ``results`` (``_Collector``)."""
    with ProgressLine(len(found.todo), f"sweep {scenario.name}", "runs", quiet=not progress) as bar:
        collector = _Collector(scenario, found, cache, identities, bar)
        for task, value in results:
            task.hand_over(value, collector)
    for message in collector.warnings:
        warnings.warn(message, stacklevel=4)  # the caller of execute's caller
    return collector
