"""Our co-simulation master: the three FMUs (FMI 2.0 or 3.0) on fmpy, a fixed or error-controlled communication
step, Gauss-Seidel or Jacobi (the loop and its policies: ``loop``, ``derivatives``)."""

from __future__ import annotations

import math
import time as clock
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict, Unpack

import numpy as np

from ..errors import CosimulationError
from ..scenario import Coupling, Interface, Order, Scenario, ScenarioError
from .derivatives import InputDerivatives
from .instance import LoadedFmu, LogMessage
from .loading import LoadedFmus
from .loop import Exchange, GaussSeidel, Jacobi, Run
from .progress import Watch
from .wiring import RunResult, Wiring

__all__ = ["CosimulationError", "CosimulationResult", "Cosimulator", "Overrides", "cosimulate"]


class Overrides(TypedDict, total=False):
    """The settings a run may take instead of its scenario's (``Scenario.with_simulation``); None: the scenario's.

    Attributes
    ----------
    step_size, stop_time, output_interval : float, optional
        Communication step ``h`` (an error-controlled run's first), stop time and recording interval, in s.
    order : Order or {"gauss-seidel", "jacobi"}, optional
        Coupling order.
    coupling : {"hold", "linear"} or Coupling, optional
        How the FMUs vary their inputs over a step (their ``coupling`` parameters; docs/co-simulation.md).
    tolerance : float, optional
        Error-controlled step (``step_control``): the estimated position error in m each step may add. A step
        that misses it is taken again, smaller, from the FMU states saved before it, within ``[h_min, h_max]``.
    input_derivatives : bool, optional
        Linear coupling through ``fmi2SetRealInputDerivatives`` with the FMUs' ``coupling`` at hold; FMI 2.0
        FMUs, a fixed step.
    """

    step_size: float | None
    stop_time: float | None
    order: Order | str | None
    output_interval: float | None
    coupling: Coupling | str | None
    tolerance: float | None
    input_derivatives: bool | None


@dataclass(kw_only=True)
class CosimulationResult(RunResult):
    """A finished run.

    Parameters
    ----------
    result : numpy.ndarray
        The recorded rows, dtype ``signals.DTYPE``, ``time`` in s first.
    wall_time : float
        s, from loading the FMUs to freeing them (a ``Cosimulator`` run: this run only).
    settings : dict
        The scenario's name, the interface and the simulation settings the run used.
    log : list of LogMessage, optional
        The FMUs' log messages.
    fmus : dict, optional
        Each FMU's ``path`` and ``build_id``, by name.
    stopped_at : float, optional
        The time in s at which the run's watch stopped it (its result ends there); None if it reached its stop time.
    steps : int
        Communication steps (the accepted ones of an error-controlled run).
    fmu_steps, rejected : int, optional
        ``doStep`` calls of all FMUs; the steps an error-controlled run took again, smaller.
    step_sizes : numpy.ndarray, optional
        Error-controlled run: every accepted step's ``time`` (its start, s), ``step_size`` (s) and
        ``estimated_error`` (m).
    """

    steps: int
    fmu_steps: int = 0
    rejected: int = 0
    step_sizes: np.ndarray | None = None


class Cosimulator:
    """The three FMUs loaded once (extracted and instantiated) for many runs.

    ``run`` co-simulates a scenario as ``cosimulate`` does, bit for bit; between runs the instances are reset
    (``fmi2Reset`` / ``fmi3Reset``), or freed and instantiated anew if that fails. ``close`` (or leaving the
    ``with`` block) frees every instance and removes the extracted folders. One Cosimulator serves one thread
    at a time.

    Parameters
    ----------
    fmu_paths : dict
        The three FMU files by name (``registry.ORDER``), each FMI 2.0 or 3.0 co-simulation.
    workdir : pathlib.Path, optional
        Where the FMUs are extracted; a temporary folder by default.

    Raises
    ------
    FmuNotFoundError
        If an FMU is not given or not a file.
    CosimulationError
        If a file is not the FMU expected (not an FMU, no co-simulation, a variable missing).
    """

    def __init__(self, fmu_paths: dict[str, Path], workdir: Path | None = None):
        self.runs = 0
        self.log: list[LogMessage] = []
        self._fmus = LoadedFmus(fmu_paths, workdir, self.log)
        self._finalizer = weakref.finalize(self, self._fmus.close)
        self.paths, self.fmus = self._fmus.paths, self._fmus.records
        try:
            self._wiring = Wiring(self._fmus.by_name)
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Cosimulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Terminate and free every instance and remove the extracted folders (idempotent)."""
        self._finalizer()

    def run(self, scenario: Scenario, *, watch: Watch | None = None,
            **settings: Unpack[Overrides]) -> CosimulationResult:
        """Co-simulate ``scenario`` as ``cosimulate`` does, bit for bit.

        Parameters
        ----------
        scenario : Scenario
            The scenario.
        watch : progress.Watch, optional
            Sees every recorded row and may stop the run there.
        **settings
            Settings replacing the scenario's (``Overrides``).

        Returns
        -------
        CosimulationResult
            As ``cosimulate``'s; ``wall_time`` counts this run only (not loading the FMUs).

        Raises
        ------
        RuntimeError
            If this Cosimulator is closed; otherwise as ``cosimulate``.
        """
        return self._run(scenario.with_simulation(**settings), watch)

    def _run(self, scenario: Scenario, watch: Watch | None = None) -> CosimulationResult:
        """``run`` of a scenario whose settings are checked already, the instances renewed first."""
        if not self._finalizer.alive:
            raise RuntimeError("this Cosimulator is closed")
        loaded = self._fmus.loaded
        _check_interfaces(scenario, loaded)
        started = clock.perf_counter()
        self._fmus.renew()
        self.runs += 1
        self.log.clear()
        settings = scenario.simulation
        run = Run(scenario, self._wiring, self.log, _exchange(settings),
                  max(1, round(settings.output_interval / settings.step_size)), watch,
                  controlled=settings.tolerance is not None)
        run.execute(loaded)
        controlled = run.step_control
        record = {"scenario": scenario.name, "interface": Interface.CO_SIMULATION, "step_size": settings.step_size,
                  "order": settings.order, "coupling": settings.coupling, "coupling_order": settings.coupling.order,
                  "stop_time": settings.stop_time, "output_interval": settings.output_interval,
                  "tolerance": settings.tolerance, "input_derivatives": settings.input_derivatives}
        if controlled is not None:
            sizes = controlled.sizes or [math.nan]
            record.update(h_min=settings.h_min, h_max=settings.h_max, step_min=min(sizes), step_max=max(sizes))
        return CosimulationResult(
            result=run.recorder.result(),
            steps=run.steps(),
            wall_time=clock.perf_counter() - started,
            settings=record,
            log=list(self.log),
            fmus={name: dict(entry) for name, entry in self.fmus.items()},
            fmu_steps=run.fmu_steps(),
            rejected=0 if controlled is None else controlled.rejected,
            step_sizes=None if controlled is None else controlled.table(),
            stopped_at=run.stopped_at,
        )


def _check_interfaces(scenario: Scenario, fmus: list[LoadedFmu]) -> None:
    """ScenarioError if the scenario asks the FMUs for what their FMI version lacks (before any FMU is touched)."""
    if scenario.simulation.input_derivatives and any(fmu.fmi_version != 2 for fmu in fmus):
        raise ScenarioError(f"{scenario.source}: [simulation] input_derivatives = true needs FMI 2.0 FMUs "
                            "(FMI 3.0 has no fmi3SetInputDerivatives); allowed: FMI 2.0 FMUs, or the coupling "
                            "parameters (input_derivatives = false)")


def _exchange(settings) -> Exchange:
    """The policy of our master for the settings: Gauss-Seidel or Jacobi, with input derivatives or without."""
    if settings.input_derivatives:
        return InputDerivatives(jacobi=not settings.order.sequential)
    return GaussSeidel() if settings.order.sequential else Jacobi()


def cosimulate(scenario: Scenario, fmu_paths: dict[str, Path], *, workdir: Path | None = None,
               watch: Watch | None = None, **settings: Unpack[Overrides]) -> CosimulationResult:
    """Co-simulate a scenario with the three FMUs (FMI 2.0 or 3.0) on fmpy.

    Communication points ``t_k = k h`` and a last, shorter step to ``stop_time``; a row at t = 0, every
    ``round(output_interval / h)`` steps and at ``stop_time`` (docs/co-simulation.md). For many runs,
    ``Cosimulator`` loads the FMUs once and gives the same results.

    Parameters
    ----------
    scenario : Scenario
        The scenario: FMU parameters and simulation settings (``scenario.simulation``).
    fmu_paths : dict
        The three FMU files by name (``registry.ORDER``).
    workdir : pathlib.Path, optional
        Where the FMUs are extracted (temporary folders, removed at the end).
    watch : progress.Watch, optional
        Called at every recorded row with its time (s) and the steps taken; when it returns False the run
        ends at that row.
    **settings
        Settings replacing the scenario's (``Overrides``).

    Returns
    -------
    CosimulationResult
        The rows (dtype ``signals.DTYPE``), the steps, the settings used and the FMUs' log.

    Raises
    ------
    ScenarioError
        For a setting out of its range, or one the FMUs' FMI version lacks.
    FmuNotFoundError
        If an FMU is not given or not a file.
    CosimulationError
        If a measurement or ``u`` is not finite or beyond ``scenario.simulation.bound`` after an exchange, if
        an FMI call fails (naming the FMU, with its last log messages), or if a step of ``h_min`` misses the
        tolerance.
    """
    scenario = scenario.with_simulation(**settings)
    started = clock.perf_counter()
    with Cosimulator(fmu_paths, workdir) as simulator:
        run = simulator._run(scenario, watch)
    run.wall_time = clock.perf_counter() - started
    return run

