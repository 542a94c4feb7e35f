"""What a sweep computes, one task at a time: a run of a case or a reference solution.

Each kind of task is a class that knows how to compute itself wherever it runs (this process, a
worker of the local pool, a Dask worker), what it becomes when the worker computing it is lost, and
which part of the sweep takes its value. The places provide the FMU files and their Cosimulator;
they never look at a task's kind.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..cosim.master import Cosimulator
from ..scenario import Scenario
from .cache import fmu_identities
from .cases import Case
from .plan import Plan
from .rows import Outcome, ReferenceOutcome, compute_reference, make_row, simulate

__all__ = ["Task", "Run", "ReferenceSolution", "run_case"]


@dataclass(frozen=True, eq=False)
class Task(ABC):
    """One computation of a sweep; ``needs_simulator`` says whether it loads the FMUs into a Cosimulator.

    Parameters
    ----------
    tag : str
        Its cache key: of the run (``cache.case_key``) or of the reference solution (``cache.reference_key``).
    applied : Scenario
        The case applied to its scenario (``cases.apply``).
    """

    tag: str
    applied: Scenario

    needs_simulator = False

    @abstractmethod
    def compute(self, fmu_paths: dict, simulator: Callable[[], Cosimulator]):
        """Compute the task where it runs.

        Parameters
        ----------
        fmu_paths : dict
            The FMU files there, by name.
        simulator : callable
            Returns the Cosimulator of the process it runs in, made on the first call.

        Returns
        -------
        object
            The task's value, for ``hand_over``.
        """

    @abstractmethod
    def lost(self, reason: str, fmu_paths: dict):
        """The value of the task once the workers computing it were lost, computed in this process.

        Parameters
        ----------
        reason : str
            Why it was lost, on one line.
        fmu_paths : dict
            The FMU files of this process, by name.

        Returns
        -------
        object
            The task's value, for ``hand_over``.
        """

    @abstractmethod
    def hand_over(self, value, sweep) -> None:
        """Give the task's value to the part of ``sweep`` that takes it.

        Parameters
        ----------
        value : object
            What ``compute`` or ``lost`` returned.
        sweep : object
            The collector of a sweep's results, with ``take_run`` and ``take_reference``.
        """


class Run(Task):
    """A co-simulation of one case (``rows.simulate``).

    Its value is an ``Outcome``, taken by ``sweep.take_run``. A run whose workers were lost is not run
    again: it is recorded as lost (``Outcome.of_lost``).

    Parameters
    ----------
    tag : str
        The run's cache key (``cache.case_key``).
    applied : Scenario
        The case applied to its scenario (``cases.apply``).
    """

    needs_simulator = True

    def compute(self, fmu_paths: dict, simulator: Callable[[], Cosimulator]) -> Outcome:
        return simulate(self.applied, simulator())

    def lost(self, reason: str, fmu_paths: dict) -> Outcome:
        return Outcome.of_lost(reason)

    def hand_over(self, value: Outcome, sweep) -> None:
        sweep.take_run(self.tag, value)


class ReferenceSolution(Task):
    """The reference solution of one physical case (``rows.compute_reference``).

    Its value is a ``rows.ReferenceOutcome`` (the solution, or why the solver failed), taken by
    ``sweep.take_reference``. A solution whose workers were lost is computed in this process.

    Parameters
    ----------
    tag : str
        The solution's cache key (``cache.reference_key``).
    applied : Scenario
        A case of it applied to its scenario (``cases.apply``).
    """

    def compute(self, fmu_paths: dict, simulator: Callable[[], Cosimulator]) -> ReferenceOutcome:
        return compute_reference(self.applied, fmu_paths)

    def lost(self, reason: str, fmu_paths: dict) -> ReferenceOutcome:
        return compute_reference(self.applied, fmu_paths)

    def hand_over(self, value: ReferenceOutcome, sweep) -> None:
        sweep.take_reference(self.tag, value)


def run_case(scenario: Scenario, case: Case, cosimulator: Cosimulator, reference: np.ndarray | None) -> dict:
    """Run one case and return its row.

    Parameters
    ----------
    scenario : Scenario
        The sweep's scenario.
    case : Case
        The case to run on it.
    cosimulator : Cosimulator
        The loaded FMUs to run it with.
    reference : numpy.ndarray or None
        The reference solution of the case's physical scenario
        (``reference_solution(apply(scenario, case), times=...)``, at least ``cache.REFERENCE_COLUMNS``),
        or None to leave the deviations NaN and judge the run as a settled one.

    Returns
    -------
    dict
        The row (``rows.make_row``).
    """
    plan = Plan.of(scenario, case, fmu_identities(cosimulator.paths))
    return make_row(plan, simulate(plan.applied, cosimulator), reference)
