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

from ..cosim.master import Cosimulator
from ..scenario import Scenario
from .rows import Outcome, compute_reference, simulate

__all__ = ["Task", "Run", "Reference"]


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
    """A co-simulation of one case: its value is an ``Outcome``; a run whose workers were lost is a lost outcome.

    Parameters
    ----------
    tag : str
        The run's cache key (``cache.case_key``).
    applied : Scenario
        The case applied to its scenario (``cases.apply``).
    """

    needs_simulator = True

    def compute(self, fmu_paths: dict, simulator: Callable[[], Cosimulator]) -> Outcome:
        """Run the case with this process's Cosimulator.

        Parameters
        ----------
        fmu_paths : dict
            The FMU files there, by name (loaded by ``simulator``).
        simulator : callable
            Returns the Cosimulator of the process it runs in.

        Returns
        -------
        Outcome
            The run's outcome (``rows.simulate``).
        """
        return simulate(self.applied, simulator())

    def lost(self, reason: str, fmu_paths: dict) -> Outcome:
        """A run whose workers were lost is not run again here: it is recorded as lost.

        Parameters
        ----------
        reason : str
            Why, on one line: the row's ``diverged_reason``.
        fmu_paths : dict
            Not used.

        Returns
        -------
        Outcome
            ``Outcome.of_lost(reason)``.
        """
        return Outcome.of_lost(reason)

    def hand_over(self, value: Outcome, sweep) -> None:
        """Give the outcome to ``sweep.take_run``.

        Parameters
        ----------
        value : Outcome
            The run's outcome.
        sweep : object
            The collector of the sweep's results.
        """
        sweep.take_run(self.tag, value)


class Reference(Task):
    """The reference solution of one physical case, computed in this process if its workers were lost.

    Its value is ``(solution or None, why it failed or None)`` (``rows.compute_reference``).

    Parameters
    ----------
    tag : str
        The solution's cache key (``cache.reference_key``).
    applied : Scenario
        A case of it applied to its scenario (``cases.apply``).
    """

    def compute(self, fmu_paths: dict, simulator: Callable[[], Cosimulator]) -> tuple:
        """Solve the reference, with the FMUs there if it goes through model exchange.

        Parameters
        ----------
        fmu_paths : dict
            The FMU files there, by name.
        simulator : callable
            Not used.

        Returns
        -------
        tuple
            The solution (``cache.REFERENCE_COLUMNS``) or None, and why the solver failed or None.
        """
        return compute_reference(self.applied, fmu_paths)

    def lost(self, reason: str, fmu_paths: dict) -> tuple:
        """Solve the reference in this process after all.

        Parameters
        ----------
        reason : str
            Not used: the reference is computed all the same.
        fmu_paths : dict
            The FMU files of this process, by name.

        Returns
        -------
        tuple
            As ``compute``.
        """
        return compute_reference(self.applied, fmu_paths)

    def hand_over(self, value: tuple, sweep) -> None:
        """Give the solution to ``sweep.take_reference``.

        Parameters
        ----------
        value : tuple
            The solution or None, and why the solver failed or None.
        sweep : object
            The collector of the sweep's results.
        """
        sweep.take_reference(self.tag, value)
