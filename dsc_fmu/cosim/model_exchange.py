"""The three FMUs as one ODE through model exchange (FMI 2.0 or 3.0): the closed loop with no coupling
error, integrated by SciPy's ``solve_ivp`` with the FMUs' event indicators as its events."""

from __future__ import annotations

import ctypes
import math
import time as clock
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from fmpy.fmi1 import FMICallException
from scipy.integrate import solve_ivp

from ..errors import CosimulationError
from ..models.parameters import DEFAULT_TOLERANCE
from ..registry import ORDER
from ..scenario import Interface, Method, Scenario, ScenarioError
from .instance import LogMessage, failed_call
from .linear import closed_loop_state_space, fmu_blocks, loop_jacobian
from .loading import LoadedFmus
from .progress import Watch
from .reference_solution import output_times
from .wiring import Recorder, RunResult, Wiring

if TYPE_CHECKING:
    import control

__all__ = ["METHOD", "DEFAULT_TOLERANCE", "ModelExchangeResult", "simulate_model_exchange", "linearise_at"]

METHOD = Method.DOP853
"""The default integrator: SciPy's explicit Runge-Kutta of order 8 (Hairer and Wanner's DOP853), as the
monolithic reference solution uses; ``Method`` names the others."""

_PAST_EVENT = 1e-9  # s: an event is handled this far past the root the solver found, on the step's interpolant


@dataclass(kw_only=True)
class ModelExchangeResult(RunResult):
    """A finished model-exchange run.

    Parameters
    ----------
    result : numpy.ndarray
        A row at every output time, dtype ``signals.DTYPE`` (the columns of co-simulation).
    wall_time : float
        s, from loading the FMUs to freeing them.
    settings : dict
        The scenario's name, the interface, the method, the tolerance, the events handled and the Jacobians
        evaluated (from the FMUs' directional derivatives).
    log : list of LogMessage, optional
        The FMUs' log messages.
    fmus : dict, optional
        Each FMU's ``path`` and ``build_id``, by name.
    stopped_at : float, optional
        The time in s at which the watch stopped the run (its last row); None if it reached its stop time.
    evaluations : int
        Derivative evaluations the solver asked for.
    """

    evaluations: int


class _Ode:
    """The loaded FMUs as one ODE, its state the reference's, the plant's and the controller's continuous states
    in that order; an evaluation sets the time and states, exchanges outputs to inputs and reads the derivatives
    or event indicators. When the watch says stop, ``stop_at`` holds that evaluation's time, where
    ``stop_event`` ends the integration."""

    def __init__(self, wiring: Wiring, bound: float, watch: Watch | None = None):
        self.wiring, self.bound, self.watch = wiring, bound, watch
        self.stop_at = None
        self.fmus = wiring.in_order()
        self.sizes = [fmu.states for fmu in self.fmus]
        self.offsets = np.cumsum([0, *self.sizes])
        self.buffers = [(ctypes.c_double * n)() for n in self.sizes]
        self.indicators = [(fmu, (ctypes.c_double * fmu.indicators)()) for fmu in self.fmus if fmu.indicators]
        self.evaluated = None
        self.at = 0.0
        self.evaluations = 0
        self.jacobian_evaluations = 0

    def load(self, t: float, y: np.ndarray) -> None:
        """The FMUs at time ``t`` and states ``y``, their inputs exchanged (once per distinct point)."""
        key = (t, y.tobytes())
        if key == self.evaluated:
            return
        self.at = t
        for fmu, buffer, start, n in zip(self.fmus, self.buffers, self.offsets, self.sizes):
            fmu.call(fmu.instance.setTime, t)
            buffer[:] = y[start:start + n]
            fmu.call(fmu.instance.setContinuousStates, buffer, n)
        self.wiring.exchange(t, self.bound)
        self.evaluated = key

    def gather(self, read) -> np.ndarray:
        """One vector of every FMU (``read(fmu, buffer, n)``), joined in order."""
        for fmu, buffer, n in zip(self.fmus, self.buffers, self.sizes):
            read(fmu, buffer, n)
        return np.concatenate([np.frombuffer(buffer) for buffer in self.buffers])

    def states(self) -> np.ndarray:
        return self.gather(lambda fmu, buffer, n: fmu.call(fmu.instance.getContinuousStates, buffer, n))

    def derivatives(self, t: float, y: np.ndarray) -> np.ndarray:
        self.evaluations += 1
        if self.watch is not None and self.stop_at is None and not self.watch(t, self.evaluations):
            self.stop_at = t
        self.load(t, y)
        return self.gather(lambda fmu, buffer, n: fmu.get_derivatives(buffer, n))

    def blocks(self) -> dict:
        """The three FMUs linearised at the loaded point (``linear.fmu_blocks``), by name: each with the
        inputs and outputs the loop connects."""
        reference, plant, controller = self.fmus
        measured = controller.real_inputs
        return {reference.name: fmu_blocks(reference, [], [n for n in measured if n in reference.real_outputs]),
                plant.name: fmu_blocks(plant, plant.real_inputs, [n for n in measured if n in plant.real_outputs]),
                controller.name: fmu_blocks(controller, measured, plant.real_inputs)}

    def jacobian(self, t: float, y: np.ndarray) -> np.ndarray:
        """The loop's Jacobian at ``t``, ``y`` from the three FMUs' directional derivatives (``linear``)."""
        self.load(t, y)
        self.jacobian_evaluations += 1
        return loop_jacobian(*self.blocks().values())

    def stop_event(self):
        """The solver's event of a stop: positive until the watch says stop, then zero at ``stop_at``
        (which lies in the step being taken), so that the solver ends there."""

        def event(t: float, y: np.ndarray) -> float:
            return 1.0 if self.stop_at is None else self.stop_at - t

        event.terminal = True
        return event

    def events(self) -> list:
        """The solver's event functions: one per event indicator of each FMU, in order."""
        return [self.indicator(fmu, buffer, index) for fmu, buffer in self.indicators for index in range(len(buffer))]

    def indicator(self, fmu, buffer, index: int):
        """The solver's event function of the event indicator ``index`` of ``fmu``, read into ``buffer``."""

        def event(t: float, y: np.ndarray) -> float:
            self.load(t, y)
            fmu.call(fmu.instance.getEventIndicators, buffer, len(buffer))
            return buffer[index]

        event.terminal = True
        return event

    def event(self) -> bool:
        """Event mode at the loaded point; whether a state changed there (``iterate``)."""
        for fmu in self.fmus:
            fmu.call(fmu.instance.enterEventMode)
        return self.iterate()

    def iterate(self) -> bool:
        """In event mode: every FMU updates its discrete states until none needs more, then all enter
        continuous-time mode; whether an FMU changed the value of a continuous state."""
        changed = False
        for fmu in self.fmus:
            needed = True
            while needed:
                needed, values_changed = fmu.update_discrete_states()
                changed = changed or values_changed
            fmu.call(fmu.instance.enterContinuousTimeMode)
        self.evaluated = None
        return changed


def _start(ode: _Ode, scenario: Scenario) -> None:
    """Initialization: parameters, the exchange at t = 0 (the controller's filters start from it), the
    first event iteration, continuous-time mode."""
    stop = scenario.simulation.stop_time
    for fmu in ode.fmus:
        fmu.enter_initialization(stop, scenario.parameters(fmu.name))
    ode.wiring.exchange(ode.at, ode.bound)
    for fmu in ode.fmus:
        fmu.call(fmu.instance.exitInitializationMode)
    ode.iterate()


def _integrate(ode: _Ode, recorder: Recorder, times: np.ndarray, tolerance: float, method: Method) -> int:
    """Integrate from the FMUs' states at 0 to ``times[-1]``, recording a row at each of ``times``;
    stop at every event, handle it just past the root and go on, until the end or the watch's stop.
    Returns the events handled. An implicit ``method`` gets the loop's Jacobian from the FMUs."""
    y = ode.states()
    atol = tolerance * ode.gather(lambda fmu, buffer, n: fmu.call(fmu.instance.getNominalsOfContinuousStates,
                                                                  buffer, n))
    events = [*ode.events(), ode.stop_event()]
    t, stop, handled = 0.0, times[-1], 0
    ode.load(t, y)
    recorder.record(t)
    pending = times[1:]
    while t < stop:
        solver_options = {"jac": ode.jacobian} if method.implicit else {}
        solution = solve_ivp(ode.derivatives, (t, stop), y, method=method.value, rtol=tolerance, atol=atol,
                             events=events, t_eval=pending, dense_output=True, **solver_options)
        if solution.status < 0:
            raise CosimulationError(f"the solver failed at t = {solution.t[-1]:.6g} s: {solution.message}",
                                    float(solution.t[-1]))
        for k, at in enumerate(solution.t):
            ode.load(at, solution.y[:, k])
            recorder.record(at)
        pending = pending[len(solution.t):]
        if len(solution.t_events[-1]):  # stopped by the watch: a last row where the solver ended
            at = float(solution.t_events[-1][0])
            if at > recorder.last_time:
                ode.load(at, solution.y_events[-1][0])
                recorder.record(at)
            break
        if solution.status == 0:
            break
        found = min(float(ts[0]) for ts in solution.t_events[:-1] if len(ts))
        t = min(found + _PAST_EVENT, stop)
        for at in pending[pending <= t]:  # output times between the root and where the event is handled
            ode.load(at, solution.sol(at))
            recorder.record(at)
        pending = pending[pending > t]
        y = solution.sol(t)
        ode.load(t, y)
        if ode.event():
            y = ode.states()
        handled += 1
    return handled


def _tolerance(scenario: Scenario, tolerance: float | None) -> float:
    """The solver's relative tolerance: ``tolerance``, else the scenario's, else ``DEFAULT_TOLERANCE``; checked."""
    rtol = next(value for value in (tolerance, scenario.simulation.tolerance, DEFAULT_TOLERANCE) if value is not None)
    if isinstance(rtol, bool) or not isinstance(rtol, (int, float)) or not (math.isfinite(rtol) and rtol > 0):
        raise ScenarioError(f"{scenario.source}: tolerance = {rtol!r} is not allowed; allowed: > 0 (the solver's "
                            "relative tolerance)")
    return rtol


def simulate_model_exchange(scenario: Scenario, fmu_paths: dict, *, stop_time: float | None = None,
                            output_interval: float | None = None, tolerance: float | None = None,
                            method: Method | str | None = None, workdir=None, watch: Watch | None = None
                            ) -> ModelExchangeResult:
    """Simulate ``scenario`` through the model-exchange interface of the FMUs in ``fmu_paths`` (by name).

    Parameters
    ----------
    scenario : Scenario
        The scenario; its parameters go to the FMUs, its ``stop_time``, ``output_interval`` and ``bound``
        apply, its co-simulation settings (step, order, coupling) do not.
    fmu_paths : dict
        The three FMU files by name (FMI 2.0 or 3.0, each with ``ModelExchange``).
    stop_time, output_interval : float, optional
        s; None takes the scenario's.
    tolerance : float, optional
        The solver's relative tolerance (each state's absolute one is this times its nominal); None takes the
        scenario's ``tolerance``, or ``DEFAULT_TOLERANCE``.
    method : {"DOP853", "Radau", "BDF"} or Method, optional
        SciPy's integrator; None takes the scenario's (``METHOD`` by default). The implicit ones get the loop's
        Jacobian, assembled from the FMUs' directional derivatives (``linear``).
    workdir : path, optional
        Where the FMUs are extracted (a temporary folder by default).
    watch : progress.Watch, optional
        Called at every derivative evaluation with its time and the evaluations so far; when it returns False
        the integration ends at that time, with a last row there.

    Returns
    -------
    ModelExchangeResult
        A row at every output time (the columns of co-simulation), the derivative evaluations, the settings.

    Raises
    ------
    CosimulationError
        A failing FMI call (naming its FMU), a signal beyond ``bound`` or the solver giving up.
    ScenarioError
        A setting out of its range.
    """
    scenario = scenario.with_simulation(stop_time=stop_time, output_interval=output_interval, method=method)
    settings = scenario.simulation
    rtol = _tolerance(scenario, tolerance)
    started = clock.perf_counter()
    log: list[LogMessage] = []
    times = output_times(settings.stop_time, settings.output_interval)
    with LoadedFmus(fmu_paths, workdir, log, model_exchange=True) as fmus:
        wiring = Wiring(fmus.by_name)
        recorder = Recorder(wiring, len(times))
        ode = _Ode(wiring, settings.bound, watch)
        try:
            _start(ode, scenario)
            events = _integrate(ode, recorder, times, rtol, settings.method)
        except FMICallException as error:
            raise failed_call(error, log, ode.at) from None
    result = recorder.result()
    return ModelExchangeResult(
        result=result, evaluations=ode.evaluations, wall_time=clock.perf_counter() - started,
        settings={"scenario": scenario.name, "interface": Interface.MODEL_EXCHANGE, "method": settings.method,
                  "tolerance": rtol, "stop_time": settings.stop_time, "output_interval": settings.output_interval,
                  "events": events, "jacobian_evaluations": ode.jacobian_evaluations},
        log=list(log), fmus=fmus.records,
        stopped_at=float(result["time"][-1]) if result["time"][-1] < settings.stop_time else None,
    )


def linearise_at(scenario: Scenario, fmu_paths: dict, at_time: float, which: str | None = None, *,
                 tolerance: float | None = None, method: Method | str | None = None, workdir=None) -> control.StateSpace:
    """One of the three FMUs, or the closed loop, linearised at a time of the scenario's model-exchange run.

    The loop is integrated as ``simulate_model_exchange`` integrates it, to ``at_time``; there each FMU's
    ``A, B, C, D`` come from its directional derivatives (``linear.fmu_blocks``), exact to rounding.

    Parameters
    ----------
    scenario : Scenario
        The scenario.
    fmu_paths : dict
        The three FMU files by name (FMI 2.0 or 3.0).
    at_time : float
        When, in s (> 0).
    which : str, optional
        An FMU's name (``registry.ORDER``): that FMU alone, its inputs and outputs those the loop connects.
        Default None: the closed loop (``linear.closed_loop_state_space``).
    tolerance : float, optional
        The solver's relative tolerance, as for ``simulate_model_exchange``.
    method : {"DOP853", "Radau", "BDF"} or Method, optional
        The integrator, as for ``simulate_model_exchange``.
    workdir : path, optional
        Where the FMUs are extracted (a temporary folder by default).

    Returns
    -------
    control.StateSpace
        The linearised system, its states, inputs and outputs named.

    Raises
    ------
    ScenarioError
        If ``which`` is not an FMU's name, or a setting is out of its range.
    CosimulationError
        A failing FMI call or the solver giving up.
    """
    if which is not None and which not in ORDER:
        raise ScenarioError(f"{which!r} is not one of the FMUs; allowed: {', '.join(ORDER)} or None (the closed loop)")
    scenario = scenario.with_simulation(stop_time=at_time, output_interval=at_time, method=method)
    rtol = _tolerance(scenario, tolerance)
    log: list[LogMessage] = []
    with LoadedFmus(fmu_paths, workdir, log, model_exchange=True) as fmus:
        wiring = Wiring(fmus.by_name)
        ode = _Ode(wiring, scenario.simulation.bound)
        try:
            _start(ode, scenario)
            _integrate(ode, Recorder(wiring, 2), np.array([0.0, at_time]), rtol, scenario.simulation.method)
            blocks = ode.blocks()
        except FMICallException as error:
            raise failed_call(error, log, ode.at) from None
    return closed_loop_state_space(blocks) if which is None else blocks[which].state_space()
