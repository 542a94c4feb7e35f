"""The co-simulation master: the three FMUs (FMI 2.0 or 3.0) on fmpy, a fixed or error-controlled communication
step, Gauss-Seidel or Jacobi."""

from __future__ import annotations

import math
import time as clock
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict, Unpack

import numpy as np
from fmpy.fmi1 import FMICallException

from ..errors import CosimulationError
from ..registry import CONTROLLER, PLANT, REFERENCE
from ..scenario import Coupling, Interface, Order, Scenario, ScenarioError
from . import signals
from .instance import LoadedFmu, LogMessage, failed_call, type_name
from .derivatives import InputRamps
from .loading import LoadedFmus
from .progress import Watch
from .step_control import ControlledSteps, defect, next_step

__all__ = [
    "CosimulationError", "CosimulationResult", "Cosimulator", "LogMessage", "Overrides", "Recorder", "Wiring",
    "check_values", "cosimulate", "step_count",
]


class Overrides(TypedDict, total=False):
    """The settings a run may take instead of its scenario's (``Scenario.with_simulation``); None: the scenario's.

    Attributes
    ----------
    step_size : float, optional
        Communication step ``h`` in s (an error-controlled run's first step).
    stop_time : float, optional
        s.
    order : Order or {"gauss-seidel", "jacobi"}, optional
        Coupling order.
    output_interval : float, optional
        Recording interval in s.
    coupling : {"hold", "linear"} or Coupling, optional
        How the FMUs vary their inputs over a step (their ``coupling`` parameters): held, or linear
        (the plant extrapolates ``u``; the controller interpolates its inputs with Gauss-Seidel,
        extrapolates them with Jacobi). The master's calls are the same.
    tolerance : float, optional
        Error-controlled step (``step_control``): the estimated position error in m each step may add.
        A step that misses it is taken again, smaller, from the FMU states saved before it; the steps
        stay within ``[h_min, h_max]`` of the scenario.
    input_derivatives : bool, optional
        Linear coupling through ``fmi2SetRealInputDerivatives`` (``derivatives.InputRamps``) with the
        FMUs' ``coupling`` at hold; FMI 2.0 FMUs, a fixed step.
    """

    step_size: float | None
    stop_time: float | None
    order: Order | str | None
    output_interval: float | None
    coupling: Coupling | str | None
    tolerance: float | None
    input_derivatives: bool | None


@dataclass
class CosimulationResult:
    """A finished run.

    Parameters
    ----------
    result : numpy.ndarray
        The recorded rows, dtype ``signals.DTYPE``, ``time`` in s first.
    steps : int
        Communication steps (the accepted ones of an error-controlled run; derivative evaluations
        for model exchange).
    wall_time : float
        s, from loading the FMUs to freeing them (a ``Cosimulator`` run: this run only).
    settings : dict
        The scenario's name, the interface and the simulation settings the run used.
    log : list of LogMessage, optional
        The FMUs' log messages.
    fmus : dict, optional
        Each FMU's ``path`` and ``build_id``, by name.
    fmu_steps : int, optional
        ``doStep`` calls of all FMUs.
    rejected : int, optional
        Error-controlled run: the steps taken again, smaller.
    step_sizes : numpy.ndarray, optional
        Error-controlled run: every accepted step, ``time`` (its start, s), ``step_size`` (s) and
        ``estimated_error`` (m).
    stopped_at : float, optional
        The time in s at which the run's watch stopped it (its result ends there); None for a run
        that reached its stop time.
    """

    result: np.ndarray
    steps: int
    wall_time: float
    settings: dict
    log: list[LogMessage] = field(default_factory=list)
    fmus: dict = field(default_factory=dict)
    fmu_steps: int = 0
    rejected: int = 0
    step_sizes: np.ndarray | None = None
    stopped_at: float | None = None


def step_count(stop_time: float, step_size: float) -> int:
    """Number of communication steps to reach ``stop_time``.

    Parameters
    ----------
    stop_time : float
        s.
    step_size : float
        Communication step in s.

    Returns
    -------
    int
        ``ceil(stop_time / step_size)``, at least 1; a ratio within 1e-9 (relative) of a whole number
        counts as that number.
    """
    ratio = stop_time / step_size
    nearest = round(ratio)
    return max(1, nearest if abs(ratio - nearest) <= 1e-9 * ratio else math.ceil(ratio))


class Cosimulator:
    """The three FMUs loaded once (extracted and instantiated) for many runs.

    ``run`` co-simulates a scenario as ``cosimulate`` does, bit for bit; between runs the instances
    are reset (``fmi2Reset`` / ``fmi3Reset``) instead of extracted again, and an instance that cannot
    be reset is freed and instantiated anew. ``close`` (or leaving the ``with`` block) frees every
    instance and removes the extracted folders. One Cosimulator serves one thread at a time; what a
    run needs beyond the loaded FMUs and their wiring lives in that run's own object.

    Parameters
    ----------
    fmu_paths : dict
        The three FMU files by name (``registry.ORDER``), each FMI 2.0 or 3.0 co-simulation (read
        from its model description), with the same variable names; the runs are the same either way.
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
        """Co-simulate ``scenario`` as ``cosimulate`` does.

        Parameters
        ----------
        scenario : Scenario
            The scenario.
        watch : progress.Watch, optional
            Sees every recorded row and may stop the run there, as for ``cosimulate``.
        **settings
            Settings replacing the scenario's (``Overrides``), as for ``cosimulate``.

        Returns
        -------
        CosimulationResult
            As ``cosimulate``'s, bit for bit; ``wall_time`` counts this run only (not loading the FMUs).

        Raises
        ------
        ScenarioError
            For a setting out of its range, or one the FMUs' FMI version lacks.
        CosimulationError
            For a run that diverges or an FMU that fails, as ``cosimulate``.
        RuntimeError
            If this Cosimulator is closed.
        """
        return self._run(scenario.with_simulation(**settings), watch)

    def _run(self, scenario: Scenario, watch: Watch | None = None) -> CosimulationResult:
        """``run`` of a scenario whose settings are checked already: every instance is brought back to
        its state after instantiation (``LoadedFmus.renew``) first."""
        if not self._finalizer.alive:
            raise RuntimeError("this Cosimulator is closed")
        loaded = self._fmus.loaded
        _check_interfaces(scenario, loaded)
        started = clock.perf_counter()
        self._fmus.renew()
        self.runs += 1
        self.log.clear()
        run = _Run(scenario, self._wiring, self.log, watch)
        run.execute(loaded)
        return CosimulationResult(
            result=run.recorder.result(),
            steps=run.steps(),
            wall_time=clock.perf_counter() - started,
            settings=run.settings_record(),
            log=list(self.log),
            fmus={name: dict(entry) for name, entry in self.fmus.items()},
            fmu_steps=run.fmu_steps(),
            rejected=0 if run.controlled is None else run.controlled.rejected,
            step_sizes=None if run.controlled is None else run.controlled.table(),
            stopped_at=run.stopped_at,
        )


class Wiring:
    """The three loaded FMUs by role and the value references of the exchange and the recording.

    Looked up once per load: a wrong FMU file fails here.

    Parameters
    ----------
    fmus : dict of str to LoadedFmu
        The loaded FMUs by name (``registry.REFERENCE``, ``registry.PLANT``, ``registry.CONTROLLER``).

    Raises
    ------
    CosimulationError
        If an FMU lacks a variable that is exchanged or recorded.
    """

    def __init__(self, fmus: dict[str, LoadedFmu]):
        for fmu in fmus.values():  # each FMU has the outputs recorded from it: a wrong file fails here
            fmu.refs(signals.RECORDED[fmu.name])
        self.fmus = fmus
        reference, plant, controller = fmus[REFERENCE], fmus[PLANT], fmus[CONTROLLER]
        measured_plant = [name for name in controller.inputs if name in plant.outputs]
        measured_reference = [name for name in controller.inputs if name not in plant.outputs]
        self.plant_out, self.reference_out = plant.refs(measured_plant), reference.refs(measured_reference)
        self.controller_in = controller.refs(measured_plant + measured_reference)
        self.controller_u, self.plant_u = controller.refs(["u1", "u2"]), plant.refs(["u1", "u2"])
        self.checked = [f"{PLANT}.{s}" for s in measured_plant] + [f"{REFERENCE}.{s}" for s in measured_reference]
        self.u_names = (f"{CONTROLLER}.u1", f"{CONTROLLER}.u2")
        self.plant, self.reference, self.controller = plant, reference, controller
        self.columns = ["time", *(name for names in signals.RECORDED.values() for name in names)]
        self.readers, offset = [], 1  # (FMU, kind, value references, table columns) of every recorded output
        for name, names in signals.RECORDED.items():
            fmu = fmus[name]
            for kind in ("Real", "Integer"):
                chosen = [i for i, output in enumerate(names) if type_name(fmu.variable(output)) == kind]
                self.readers.append((fmu, kind, fmu.refs([names[i] for i in chosen]), [offset + i for i in chosen]))
            offset += len(names)


    def measure(self, at: float, bound: float) -> list:
        """The controller's measurements: the plant's and the reference's outputs, checked.

        Parameters
        ----------
        at : float
            Simulated time in s, for the message of a divergence.
        bound : float
            Largest magnitude allowed (``Simulation.bound``).

        Returns
        -------
        list of float
            The measurements, in the order of ``controller_in``.

        Raises
        ------
        CosimulationError
            At the first measurement that is not finite or beyond ``bound``.
        """
        measured = self.plant.slave.getReal(self.plant_out) + self.reference.slave.getReal(self.reference_out)
        check_values(measured, self.checked, at, bound)
        return measured

    def pass_u(self, at: float, bound: float) -> list:
        """The controller's ``u``, checked, set on the plant.

        Parameters
        ----------
        at : float
            Simulated time in s, for the message of a divergence.
        bound : float
            Largest magnitude allowed in V (``Simulation.bound``).

        Returns
        -------
        list of float
            ``[u1, u2]`` in V.

        Raises
        ------
        CosimulationError
            If a voltage is not finite or beyond ``bound``.
        """
        u = self.controller.slave.getReal(self.controller_u)
        check_values(u, self.u_names, at, bound)
        self.plant.slave.setReal(self.plant_u, u)
        return u


class _Run:
    """One run: its scenario and settings (validated where they entered), the FMUs by role, the
    recorder, the voltages of the last exchange, the master's input ramps, the error-controlled
    steps, where the run is (for the message of a failure), its watch and where that stopped it."""

    def __init__(self, scenario: Scenario, wiring: Wiring, log: list[LogMessage], watch: Watch | None = None):
        self.scenario, self.settings, self.wiring, self.log = scenario, scenario.simulation, wiring, log
        fmus = wiring.fmus
        self.reference, self.plant, self.controller = (fmus[name].slave for name in (REFERENCE, PLANT, CONTROLLER))
        settings = self.settings
        self.n = step_count(settings.stop_time, settings.step_size)
        self.every = max(1, round(settings.output_interval / settings.step_size))
        self.recorder = Recorder(wiring, self.n // self.every + 1 + (self.n % self.every != 0))
        self.at = (0, 0.0)
        self.u = None
        self.ramps = self._input_ramps() if settings.input_derivatives else None
        self.controlled = None
        self.watch = watch
        self.stopped_at = None

    def execute(self, fmus: list[LoadedFmu]) -> None:
        """Initialise the FMUs (in ``fmus``' order) and run; every FMU is terminated at the end."""
        settings = self.settings
        try:
            for fmu in fmus:
                fmu.initialise(settings.stop_time,
                               self.scenario.parameters(fmu.name, slopes_from_master=settings.input_derivatives))
            if settings.tolerance is None:
                self._steps()
            else:
                self.controlled = self._controlled()
        except CosimulationError as error:
            error.result, error.steps = self.recorder.result(), self.at[0]
            raise
        except FMICallException as error:
            raise self._failure(error) from None
        finally:
            for fmu in reversed(fmus):
                fmu.terminate()

    def steps(self) -> int:
        """The communication steps taken (accepted ones, for an error-controlled run)."""
        return self.n if self.controlled is None else len(self.controlled.times)

    def fmu_steps(self) -> int:
        return 3 * self.n if self.controlled is None else self.controlled.fmu_steps

    def settings_record(self) -> dict:
        """The settings the run used: for an error-controlled run also the allowed step range and the
        range of the steps it took."""
        settings = self.settings
        record = {"scenario": self.scenario.name, "interface": Interface.CO_SIMULATION,
                  "step_size": settings.step_size, "order": settings.order, "coupling": settings.coupling,
                  "coupling_order": settings.coupling.order, "stop_time": settings.stop_time,
                  "output_interval": settings.output_interval, "tolerance": settings.tolerance,
                  "input_derivatives": settings.input_derivatives}
        if self.controlled is not None:
            sizes = self.controlled.sizes or [math.nan]
            record.update(h_min=settings.h_min, h_max=settings.h_max, step_min=min(sizes), step_max=max(sizes))
        return record

    def _steps(self) -> None:
        """The exchanges and steps of a fixed-step run, as ``cosimulate`` describes them; ``at`` follows
        (steps completed, time) for the messages of a failure. A watch that says stop at a row ends
        the run there (``n`` becomes the steps taken)."""
        h, stop, n, every = self.settings.step_size, self.settings.stop_time, self.n, self.every
        self._start()
        for k in range(n):
            t = k * h
            self.at = (k, t)
            end = stop if k == n - 1 else (k + 1) * h
            self._advance(t, end - t if k == n - 1 else h, end)
            if (k + 1) % every == 0 or k == n - 1:
                self.recorder.record(end)
                if self._stops(end, k + 1, k == n - 1):
                    self.n = k + 1
                    return

    def _stops(self, at: float, steps: int, last: bool) -> bool:
        """Whether the watch stops the run at the row just recorded at ``at`` (noted in ``stopped_at``);
        the ``last`` row is shown to the watch but ends the run anyway."""
        if self.watch is None or self.watch(at, steps) or last:
            return False
        self.stopped_at = at
        return True

    def _start(self) -> None:
        """The measurements at t = 0 (checked), the exchange there and its row."""
        wiring = self.wiring
        measurements = wiring.measure(0.0, self.settings.bound)
        self._exchange(0.0, measurements, True)
        self.recorder.record(0.0)

    def _advance(self, t: float, step: float, end: float) -> list:
        """One communication step of ``step`` from ``t`` and the exchange at its ``end``: the reference
        and the plant step, then (Gauss-Seidel) the controller's inputs are set from their new outputs,
        the controller steps, and its ``u`` goes to the plant. Returns the measurements at ``end``."""
        wiring, ramps = self.wiring, self.ramps
        jacobi = not self.settings.order.sequential
        if ramps is not None:
            ramps.before_plant()
        self.reference.doStep(t, step)
        self.plant.doStep(t, step)
        measured = wiring.measure(end, self.settings.bound)
        if ramps is not None:
            ramps.before_controller(step, measured)
        elif not jacobi:
            self.controller.setReal(wiring.controller_in, measured)
        self.controller.doStep(t, step)
        self.at = (self.at[0] + 1, end)
        self._exchange(end, measured, jacobi or ramps is not None)
        return measured

    def _input_ramps(self) -> InputRamps:
        """The master's input derivatives for the linear coupling (FMI 2.0 FMUs: ``_check_interfaces``)."""
        wiring = self.wiring
        return InputRamps(self.plant, wiring.plant_u, self.controller, wiring.controller_in,
                          not self.settings.order.sequential)

    def _controlled(self) -> ControlledSteps:
        """An error-controlled run (``step_control``): each step's position error estimated from the
        defect of ``u`` at its end; a step that misses the tolerance is taken again, smaller, from the
        FMU states saved before it."""
        settings = self.settings
        tolerance, order, gain = settings.tolerance, settings.coupling.order, settings.error_gain
        h_min, h_max, stop = settings.h_min, settings.h_max, settings.stop_time
        slaves = [self.reference, self.plant, self.controller]
        done = ControlledSteps()
        self._start()
        u, u_before, h_before = self.u, None, None
        t, h = 0.0, min(h_max, max(h_min, settings.step_size))
        while t < stop:
            h = min(h, stop - t)
            end = stop if stop - t - h < h_min * (1 - 1e-9) else t + h  # no last step shorter than h_min
            taken = end - t
            smallest = taken <= h_min * (1 + 1e-9)  # end - t rounds: h_min may come out a little larger
            self.at = (len(done.times), t)
            saved = [slave.getFMUState() for slave in slaves]
            try:
                try:
                    self._advance(t, taken, end)
                    error = gain * defect(u, self.u, u_before if order == 2 else None, taken, h_before)
                except (CosimulationError, FMICallException):
                    if smallest:
                        raise
                    error = math.inf  # a step that diverges or that an FMU discards is too long
                done.fmu_steps += 3
                if error <= tolerance:
                    done.times.append(t)
                    done.sizes.append(taken)
                    done.errors.append(error)
                    t, u, u_before, h_before = end, self.u, u, taken
                    self.recorder.record(t)
                    if self._stops(t, len(done.times), t >= stop):
                        break
                elif smallest:
                    raise CosimulationError(
                        f"the error-controlled step cannot meet the tolerance {tolerance:g} m at t = {t:.6g} s: the "
                        f"estimated error of a step of h_min = {h_min:g} s is {error:.3g} m; allowed: a smaller "
                        f"h_min or a larger tolerance{' (or the linear coupling)' if order == 1 else ''}", t)
                else:
                    done.rejected += 1
                    for slave, state in zip(slaves, saved):
                        slave.setFMUState(state)
            finally:
                for slave, state in zip(slaves, saved):
                    slave.freeFMUState(state)
            h = next_step(taken, error, tolerance, order, h_min, h_max)
        return done

    def _exchange(self, at: float, measurements: list, set_inputs: bool) -> None:
        """The exchange at a communication point: the controller's inputs (if ``set_inputs``), then
        its ``u`` (checked) to the plant."""
        wiring = self.wiring
        if set_inputs:
            self.controller.setReal(wiring.controller_in, measurements)
        u = wiring.pass_u(at, self.settings.bound)
        self.u = u
        if self.ramps is not None:
            self.ramps.exchanged(at, u, measurements)

    def _failure(self, error: FMICallException) -> CosimulationError:
        """The CosimulationError of a failing FMI call: the FMU that the call named, the time and that
        FMU's last log messages."""
        k, t = self.at
        failure = failed_call(error, self.log, t)
        failure.result, failure.steps = self.recorder.result(), k
        return failure


def _check_interfaces(scenario: Scenario, fmus: list[LoadedFmu]) -> None:
    """ScenarioError if the scenario asks the FMUs for what their FMI version lacks (before any FMU is touched)."""
    if scenario.simulation.input_derivatives and any(fmu.fmi_version != 2 for fmu in fmus):
        raise ScenarioError(f"{scenario.source}: [simulation] input_derivatives = true needs FMI 2.0 FMUs "
                            "(FMI 3.0 has no fmi3SetInputDerivatives); allowed: FMI 2.0 FMUs, or the coupling "
                            "parameters (input_derivatives = false)")


def check_values(values, names, at: float, bound: float) -> None:
    """Check that every value is finite and within ``bound`` in magnitude.

    Parameters
    ----------
    values : sequence of float
        The values.
    names : sequence of str
        Their names (``FMU.variable``), in the same order.
    at : float
        Simulated time in s, for the message.
    bound : float
        Largest magnitude allowed.

    Raises
    ------
    CosimulationError
        At the first value that is not finite or exceeds ``bound``, naming it.
    """
    for name, value in zip(names, values):
        if not -bound <= value <= bound:
            reason = "is not finite" if not math.isfinite(value) else f"exceeds the bound {bound:g}"
            raise CosimulationError(f"diverged at t = {at:.6g} s: {name} = {value:.6g} {reason}", at, name, value)


class Recorder:
    """The rows of one run: ``time`` and every output of ``signals.RECORDED``, read at each ``record``.

    Parameters
    ----------
    wiring : Wiring
        The loaded FMUs and the value references of their recorded outputs.
    rows : int
        Rows to allocate; an error-controlled run grows the table as it needs.
    """

    def __init__(self, wiring: Wiring, rows: int):
        self.columns = wiring.columns
        self.table = np.full((rows, len(self.columns)), np.nan)
        self.rows = 0
        self.readers = [((fmu.slave.getReal if kind == "Real" else fmu.slave.getInteger), refs, cols)
                        for fmu, kind, refs, cols in wiring.readers if refs]

    def record(self, at: float) -> None:
        """Read a row: every recorded output now, stamped with ``at``.

        Parameters
        ----------
        at : float
            The row's time in s.
        """
        if self.rows == len(self.table):  # an error-controlled run: as many rows as accepted steps
            self.table = np.concatenate([self.table, np.full_like(self.table, np.nan)])
        table, row = self.table, self.rows
        table[row, 0] = at
        for get, refs, cols in self.readers:
            table[row, cols] = get(refs)
        self.rows = row + 1

    @property
    def last_time(self) -> float:
        """The time in s of the last row recorded."""
        return float(self.table[self.rows - 1, 0])

    def result(self) -> np.ndarray:
        """The rows recorded so far, with the tracking errors.

        Returns
        -------
        numpy.ndarray
            dtype ``signals.DTYPE``.
        """
        return _result(self.table[: self.rows], self.columns)


def cosimulate(scenario: Scenario, fmu_paths: dict[str, Path], *, workdir: Path | None = None,
               watch: Watch | None = None, **settings: Unpack[Overrides]) -> CosimulationResult:
    """Co-simulate a scenario with the three FMUs (FMI 2.0 or 3.0) on fmpy.

    Communication points are ``t_k = k h`` for ``k < n = step_count(stop_time, h)`` and ``t_n = stop_time``
    (a last, shorter step); at each one the controller's inputs are set from the plant's and the
    reference's outputs and its ``u`` goes to the plant, then the FMUs step (Gauss-Seidel: reference
    and plant first, the controller with their outputs at ``t_{k+1}``; Jacobi: all three from ``t_k``).
    Rows are recorded at ``t = 0``, every ``round(output_interval / h)`` steps and at ``stop_time``
    (an error-controlled run: at every accepted step). docs/co-simulation.md gives the details; for
    many runs, load the FMUs once with ``Cosimulator``: its runs give the same results.

    Parameters
    ----------
    scenario : Scenario
        The scenario: FMU parameters and simulation settings (``scenario.simulation``).
    fmu_paths : dict
        The three FMU files by name (``registry.ORDER``).
    workdir : pathlib.Path, optional
        Where the FMUs are extracted (temporary folders, removed at the end).
    watch : progress.Watch, optional
        Called at every recorded row with its time (s) and the steps taken; when it returns False
        the run ends at that row.
    **settings
        Settings replacing the scenario's (``Overrides``): ``step_size``, ``stop_time``, ``order``,
        ``output_interval``, ``coupling``, ``tolerance``, ``input_derivatives``.

    Returns
    -------
    CosimulationResult
        The rows (dtype ``signals.DTYPE``: every output of ``signals.RECORDED``, then the tracking
        errors), the steps, the settings used and the FMUs' log.

    Raises
    ------
    ScenarioError
        For a setting out of its range (a setting left as None is the scenario's, checked already),
        or one the FMUs' FMI version lacks.
    FmuNotFoundError
        If an FMU is not given or not a file.
    CosimulationError
        If a measurement or ``u`` is not finite or beyond ``scenario.simulation.bound`` after an
        exchange, if an FMI call fails (naming the FMU, with its last log messages), or if a step of
        ``h_min`` misses the tolerance.
    """
    scenario = scenario.with_simulation(**settings)
    started = clock.perf_counter()
    with Cosimulator(fmu_paths, workdir) as simulator:
        run = simulator._run(scenario, watch)
    run.wall_time = clock.perf_counter() - started
    return run


def _result(table: np.ndarray, columns: list[str]) -> np.ndarray:
    """``table`` (columns named by ``columns``) as a ``signals.DTYPE`` array with the tracking errors."""
    result = np.zeros(len(table), dtype=signals.DTYPE)
    for index, name in enumerate(columns):
        result[name] = table[:, index]
    signals.add_tracking_errors(result)
    return result
