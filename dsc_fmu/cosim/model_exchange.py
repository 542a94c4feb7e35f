"""The three FMUs as one ODE through model exchange (FMI 2.0 or 3.0): the closed loop with no coupling
error, integrated by SciPy's ``solve_ivp`` with the FMUs' event indicators as its events."""

from __future__ import annotations

import ctypes
import math
import time as clock
from typing import TYPE_CHECKING

import numpy as np
from fmpy.fmi1 import FMICallException
from scipy.integrate import solve_ivp

from ..errors import CosimulationError
from ..models.parameters import DEFAULT_TOLERANCE
from ..registry import ORDER
from ..scenario import Interface, Method, Scenario, ScenarioError
from .instance import LogMessage, failed_call
from .linear import closed_loop, fmu_blocks, loop_jacobian
from .loading import LoadedFmus
from .master import CosimulationResult, Wiring, Recorder
from .progress import Watch
from .reference_solution import output_times

if TYPE_CHECKING:
    import control

__all__ = ["METHOD", "DEFAULT_TOLERANCE", "simulate_model_exchange", "linearise_at"]

METHOD = Method.DOP853
"""The default integrator: SciPy's explicit Runge-Kutta of order 8 (Hairer and Wanner's DOP853), as the
monolithic reference solution uses; ``Method`` names the others."""

_PAST_EVENT = 1e-9  # s: an event is handled this far past the root the solver found, on the step's interpolant


class _Loop:
    """The loaded FMUs as one ODE: the state vector is the reference's, the plant's and the controller's
    continuous states in that order; each evaluation sets the time and states, passes outputs to inputs
    in dependency order (reference and plant, then the controller, then the plant's voltages) and reads
    the derivatives or the event indicators. A watch sees every derivative evaluation; when it says
    stop, ``stop_at`` holds that evaluation's time, where ``stop_event`` then ends the integration."""

    def __init__(self, wiring: Wiring, bound: float, watch: Watch | None = None):
        self.wiring, self.bound, self.watch = wiring, bound, watch
        self.stop_at = None
        self.models = [wiring.fmus[name].slave for name in ORDER]
        self.sizes = [wiring.fmus[name].states for name in ORDER]
        self.offsets = np.cumsum([0, *self.sizes])
        self.buffers = [(ctypes.c_double * n)() for n in self.sizes]
        self.indicators = (ctypes.c_double * wiring.controller.indicators)()
        self.evaluated = None
        self.at = 0.0
        self.evaluations = 0
        self.jacobians = 0

    def exchange(self) -> None:
        """Outputs to inputs at the current time and states (checked against the bound)."""
        wiring = self.wiring
        wiring.controller.slave.setReal(wiring.controller_in, wiring.measure(self.at, self.bound))
        wiring.pass_u(self.at, self.bound)

    def load(self, t: float, y: np.ndarray) -> None:
        """The FMUs at time ``t`` and states ``y``, their inputs exchanged (once per distinct point)."""
        key = (t, y.tobytes())
        if key == self.evaluated:
            return
        self.at = t
        for model, buffer, start, n in zip(self.models, self.buffers, self.offsets, self.sizes):
            model.setTime(t)
            buffer[:] = y[start:start + n]
            model.setContinuousStates(buffer, n)
        self.exchange()
        self.evaluated = key

    def gather(self, method: str) -> np.ndarray:
        """One vector of every FMU (``method``: getContinuousStates, getDerivatives, ...), joined in order."""
        for model, buffer, n in zip(self.models, self.buffers, self.sizes):
            getattr(model, method)(buffer, n)
        return np.concatenate([np.frombuffer(buffer) for buffer in self.buffers])

    def derivatives(self, t: float, y: np.ndarray) -> np.ndarray:
        self.evaluations += 1
        if self.watch is not None and self.stop_at is None and not self.watch(t, self.evaluations):
            self.stop_at = t
        self.load(t, y)
        return self.gather("getDerivatives")

    def blocks(self) -> dict:
        """The three FMUs linearised at the loaded point (``linear.fmu_blocks``), by name: each with the
        inputs and outputs the loop connects."""
        fmus = self.wiring.fmus
        reference, plant, controller = (fmus[name] for name in ORDER)
        measured = controller.real_inputs
        return {reference.name: fmu_blocks(reference, [], [n for n in measured if n in reference.real_outputs]),
                plant.name: fmu_blocks(plant, plant.real_inputs, [n for n in measured if n in plant.real_outputs]),
                controller.name: fmu_blocks(controller, measured, plant.real_inputs)}

    def jacobian(self, t: float, y: np.ndarray) -> np.ndarray:
        """The loop's Jacobian at ``t``, ``y`` from the three FMUs' directional derivatives (``linear``)."""
        self.load(t, y)
        self.jacobians += 1
        return loop_jacobian(*self.blocks().values())

    def stop_event(self):
        """The solver's event of a stop: positive until the watch says stop, then zero at ``stop_at``
        (which lies in the step being taken), so that the solver ends there."""

        def event(t: float, y: np.ndarray) -> float:
            return 1.0 if self.stop_at is None else self.stop_at - t

        event.terminal = True
        return event

    def indicator(self, index: int):
        """The solver's event function of the controller's event indicator ``index``."""

        def event(t: float, y: np.ndarray) -> float:
            self.load(t, y)
            self.wiring.controller.slave.getEventIndicators(self.indicators, len(self.indicators))
            return self.indicators[index]

        event.terminal = True
        return event

    def event(self) -> bool:
        """Event mode at the loaded point; whether a state changed there (``iterate``)."""
        for model in self.models:
            model.enterEventMode()
        return self.iterate()

    def iterate(self) -> bool:
        """In event mode: every FMU updates its discrete states until none needs more, then all enter
        continuous-time mode; whether an FMU changed the value of a continuous state."""
        changed = False
        for model in self.models:
            while True:
                needed, _, _, values_changed, _, _ = model.newDiscreteStates()
                changed = changed or values_changed
                if not needed:
                    break
            model.enterContinuousTimeMode()
        self.evaluated = None
        return changed


def _start(loop: _Loop, scenario: Scenario) -> None:
    """Initialization: parameters, the exchange at t = 0 (the controller's filters start from it), the
    first event iteration, continuous-time mode."""
    fmus, stop = loop.wiring.fmus, scenario.simulation.stop_time
    for name in ORDER:
        fmus[name].enter_initialization(stop, scenario.parameters(name))
    loop.exchange()
    for model in loop.models:
        model.exitInitializationMode()
    loop.iterate()


def _integrate(loop: _Loop, recorder: Recorder, times: np.ndarray, tolerance: float, method: Method) -> int:
    """Integrate from the FMUs' states at 0 to ``times[-1]``, recording a row at each of ``times``;
    stop at every event, handle it just past the root and go on, until the end or the watch's stop.
    Returns the events handled. An implicit ``method`` gets the loop's Jacobian from the FMUs."""
    y = loop.gather("getContinuousStates")
    atol = tolerance * loop.gather("getNominalsOfContinuousStates")
    events = [*(loop.indicator(i) for i in range(len(loop.indicators))), loop.stop_event()]
    t, stop, handled = 0.0, times[-1], 0
    loop.load(t, y)
    recorder.record(t)
    pending = times[1:]
    while t < stop:
        jacobian = {"jac": loop.jacobian} if method.implicit else {}
        solution = solve_ivp(loop.derivatives, (t, stop), y, method=method.value, rtol=tolerance, atol=atol,
                             events=events, t_eval=pending, dense_output=True, **jacobian)
        if solution.status < 0:
            raise CosimulationError(f"the solver failed at t = {solution.t[-1]:.6g} s: {solution.message}",
                                    float(solution.t[-1]))
        for k, at in enumerate(solution.t):
            loop.load(at, solution.y[:, k])
            recorder.record(at)
        pending = pending[len(solution.t):]
        if len(solution.t_events[-1]):  # stopped by the watch: a last row where the solver ended
            at = float(solution.t_events[-1][0])
            if at > recorder.last_time:
                loop.load(at, solution.y_events[-1][0])
                recorder.record(at)
            break
        if solution.status == 0:
            break
        found = min(float(ts[0]) for ts in solution.t_events[:-1] if len(ts))
        t = min(found + _PAST_EVENT, stop)
        for at in pending[pending <= t]:  # output times between the root and where the event is handled
            loop.load(at, solution.sol(at))
            recorder.record(at)
        pending = pending[pending > t]
        y = solution.sol(t)
        loop.load(t, y)
        if loop.event():
            y = loop.gather("getContinuousStates")
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
                            ) -> CosimulationResult:
    """Simulate ``scenario`` through the model-exchange interface of the FMUs in ``fmu_paths`` (by name).

    Parameters
    ----------
    scenario : Scenario
        The scenario; its parameters go to the FMUs, its ``stop_time``, ``output_interval`` and
        ``bound`` apply.
    fmu_paths : dict
        The three FMU files by name (FMI 2.0 or 3.0, each with ``ModelExchange``).
    stop_time, output_interval : float, optional
        s; None takes the scenario's.
    tolerance : float, optional
        The solver's relative tolerance (each state's absolute tolerance is this times its nominal);
        None takes the scenario's ``tolerance``, or ``DEFAULT_TOLERANCE``. The scenario's co-simulation
        settings (step, order, coupling) do not apply.
    method : {"DOP853", "Radau", "BDF"} or Method, optional
        SciPy's integrator; None takes the scenario's (``METHOD`` by default). The implicit ones get the
        loop's Jacobian, assembled from the FMUs' directional derivatives (``linear``).
    workdir : path, optional
        Where the FMUs are extracted (a temporary folder by default).
    watch : progress.Watch, optional
        Called at every derivative evaluation with its time and the evaluations so far; when it
        returns False the integration ends at that time, with a last row there.

    Returns
    -------
    CosimulationResult
        ``result`` has a row at every output time (the same columns as co-simulation); ``steps`` counts
        the derivative evaluations, ``settings`` names the interface, the method, the tolerance and the
        Jacobians evaluated; ``stopped_at``
        is where the watch stopped the run (its last row), else None.

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
        loop = _Loop(wiring, settings.bound, watch)
        try:
            _start(loop, scenario)
            events = _integrate(loop, recorder, times, rtol, settings.method)
        except FMICallException as error:
            raise failed_call(error, log, loop.at) from None
    result = recorder.result()
    return CosimulationResult(
        result=result, steps=loop.evaluations, wall_time=clock.perf_counter() - started,
        settings={"scenario": scenario.name, "interface": Interface.MODEL_EXCHANGE, "method": settings.method,
                  "tolerance": rtol, "stop_time": settings.stop_time, "output_interval": settings.output_interval,
                  "events": events, "jacobians": loop.jacobians},
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
        An FMU's name (``registry.ORDER``): that FMU alone, its inputs and outputs those the loop
        connects. Default None: the closed loop (``linear.closed_loop``).
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
        loop = _Loop(wiring, scenario.simulation.bound)
        try:
            _start(loop, scenario)
            _integrate(loop, Recorder(wiring, 2), np.array([0.0, at_time]), rtol, scenario.simulation.method)
            blocks = loop.blocks()
        except FMICallException as error:
            raise failed_call(error, log, loop.at) from None
    return closed_loop(blocks) if which is None else blocks[which].state_space()
