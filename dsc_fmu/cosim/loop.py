"""The co-simulation loop, one for every master: initialise the FMUs, then step them at fixed or error-controlled
communication points, the exchange around each step a policy (``Exchange``: ours, ``derivatives``, ``exchange``)."""

from __future__ import annotations

import math
from collections.abc import Iterator

from fmpy.fmi1 import FMICallException

from ..errors import CosimulationError
from ..scenario import Scenario
from .instance import LoadedFmu, LogMessage, failed_call
from .progress import Watch
from .step_control import ControlledSteps, defect, next_step
from .wiring import Recorder, Wiring

__all__: list[str] = []  # the package's own: Run, Exchange, GaussSeidel, Jacobi, step_count


def step_count(stop_time: float, step_size: float) -> int:
    """Communication steps to reach ``stop_time``: ``ceil(stop_time / step_size)``, at least 1; a ratio within
    1e-9 (relative) of a whole number counts as that number."""
    ratio = stop_time / step_size
    nearest = round(ratio)
    return max(1, nearest if abs(ratio - nearest) <= 1e-9 * ratio else math.ceil(ratio))


class Exchange:
    """How a master moves values between the FMUs around their steps: the policy of a ``Run``.

    This base has our master's schedule: communication points ``t_k = k h`` with a last, shorter step
    to the stop time; parameters set in initialisation mode; at t = 0 the exchange (the controller's
    inputs from the plant's and the reference's outputs, then its ``u`` to the plant) and a row.
    Subclasses say what happens around each step (``step``).
    """

    parameters_first = False
    """The parameters are set before initialisation mode, not in it."""
    sets_slopes = False
    """The master sets the inputs' slopes (fmi2SetRealInputDerivatives): the FMUs' ``coupling`` is hold."""

    def stop_time(self, stop: float) -> float | None:
        """The stop time in s passed to the FMUs at set-up (None: none)."""
        return stop

    def step_count(self, h: float, stop: float) -> int:
        """How many steps ``time_points`` gives."""
        return step_count(stop, h)

    def time_points(self, h: float, stop: float) -> Iterator[tuple[float, float, float, float]]:
        """(start, step, end, row time) of every step, in s."""
        n = step_count(stop, h)
        for k in range(n - 1):
            yield k * h, h, (k + 1) * h, (k + 1) * h
        yield (n - 1) * h, stop - (n - 1) * h, stop, stop

    def initialise(self, run: Run) -> None:
        """What happens in initialisation mode, after the parameters."""

    def start(self, run: Run) -> None:
        """What happens after initialisation, before the first step."""
        run.u = run.wiring.exchange(0.0, run.bound)
        run.recorder.record(0.0)

    def step(self, run: Run, t: float, h: float, end: float) -> None:
        """One step of every FMU from ``t`` over ``h`` to ``end`` (s), and the exchange around it."""
        raise NotImplementedError


class GaussSeidel(Exchange):
    """Ours, sequential: the reference and the plant step; the controller gets their outputs at the step's
    end, steps, and its ``u`` goes to the plant."""

    def step(self, run: Run, t: float, h: float, end: float) -> None:
        wiring = run.wiring
        run.reference.do_step(t, h)
        run.plant.do_step(t, h)
        wiring.measurements.set(wiring.measurements.read(end, run.bound))
        run.controller.do_step(t, h)
        run.stepped(end)
        u = wiring.voltages.read(end, run.bound)
        wiring.voltages.set(u)
        run.u = u


class Jacobi(Exchange):
    """Ours, parallel: all three step from ``t`` with the inputs of ``t``, then the exchange at the end."""

    def step(self, run: Run, t: float, h: float, end: float) -> None:
        run.reference.do_step(t, h)
        run.plant.do_step(t, h)
        measured = run.wiring.measurements.read(end, run.bound)
        run.controller.do_step(t, h)
        run.stepped(end)
        run.u = run.wiring.exchange(end, run.bound, measured)


class Run:
    """One run of the loop: the scenario (settings checked), the wired FMUs, the ``exchange`` policy, a row
    every ``every`` fixed steps (every accepted one if ``controlled``: ``step_control``), the ``log`` for the
    message of a failing call, a ``watch`` that may stop the run at a row, a ``trace`` told ``stepped(t,
    end)`` when every FMU has stepped (``exchange`` records what each FMU held); where the run is (``at``:
    steps done, time), the last ``u``, and where the watch stopped it."""

    def __init__(self, scenario: Scenario, wiring: Wiring, log: list[LogMessage], exchange: Exchange, every: int,
                 watch: Watch | None = None, *, controlled: bool = False, trace=None):
        self.scenario, self.settings, self.wiring, self.log = scenario, scenario.simulation, wiring, log
        self.exchange, self.every, self.watch, self.trace = exchange, every, watch, trace
        self.controlled = controlled
        self.bound = self.settings.bound
        self.reference, self.plant, self.controller = wiring.reference, wiring.plant, wiring.controller
        self.n = exchange.step_count(self.settings.step_size, self.settings.stop_time)
        self.recorder = Recorder(wiring, self.n // every + 2)
        self.at = (0, 0.0)
        self.u = None
        self.step_control: ControlledSteps | None = None
        self.stopped_at = None

    def execute(self, fmus: list[LoadedFmu]) -> None:
        """Initialise the FMUs (in ``fmus``' order) and run, terminating them at the end; a CosimulationError
        (a divergence, a failing call naming its FMU, a tolerance not met) holds the rows and steps done."""
        settings, exchange = self.settings, self.exchange
        try:
            for fmu in fmus:
                fmu.enter_initialization(
                    exchange.stop_time(settings.stop_time),
                    self.scenario.parameters(fmu.name, slopes_from_master=exchange.sets_slopes),
                    set_first=exchange.parameters_first)
            exchange.initialise(self)
            for fmu in fmus:
                fmu.call(fmu.instance.exitInitializationMode)
            exchange.start(self)
            if self.controlled:
                self.step_control = self._controlled()
            else:
                self._fixed()
        except CosimulationError as error:
            error.result, error.steps = self.recorder.result(), self.at[0]
            raise
        except FMICallException as error:
            failure = failed_call(error, self.log, self.at[1])
            failure.result, failure.steps = self.recorder.result(), self.at[0]
            raise failure from None
        finally:
            for fmu in reversed(fmus):
                fmu.terminate()

    def stepped(self, end: float) -> None:
        """Every FMU has stepped to ``end`` (s)."""
        if self.trace is not None:
            self.trace.stepped(self.at[1], end)
        self.at = (self.at[0] + 1, end)

    def steps(self) -> int:
        """The communication steps taken (accepted ones, for an error-controlled run)."""
        return self.n if self.step_control is None else len(self.step_control.times)

    def fmu_steps(self) -> int:
        return 3 * self.n if self.step_control is None else self.step_control.fmu_steps

    def _fixed(self) -> None:
        """The exchange's ``time_points``, a row every ``every`` and at the end; a watch that says stop at a row
        ends the run there (``n`` becomes the steps taken)."""
        every, last, step = self.every, self.n - 1, self.exchange.step
        points = self.exchange.time_points(self.settings.step_size, self.settings.stop_time)
        for k, (t, h, end, stamp) in enumerate(points):
            self.at = (k, t)
            step(self, t, h, end)
            if (k + 1) % every == 0 or k == last:
                self.recorder.record(stamp)
                if self._stops(stamp, k + 1, k == last):
                    self.n = k + 1
                    return

    def _stops(self, at: float, steps: int, last: bool) -> bool:
        """Whether the watch stops the run at the row just recorded at ``at`` (noted in ``stopped_at``);
        the ``last`` row is shown to the watch but ends the run anyway."""
        if self.watch is None or self.watch(at, steps) or last:
            return False
        self.stopped_at = at
        return True

    def _controlled(self) -> ControlledSteps:
        """An error-controlled run (``step_control``): each step's position error estimated from the
        defect of ``u`` at its end; a step that misses the tolerance is taken again, smaller, from the
        FMU states saved before it."""
        settings = self.settings
        tolerance, order, gain = settings.tolerance, settings.coupling.order, settings.error_gain
        h_min, h_max, stop = settings.h_min, settings.h_max, settings.stop_time
        fmus = self.wiring.in_order()
        done = ControlledSteps()
        u, u_before, h_before = self.u, None, None
        t, h = 0.0, min(h_max, max(h_min, settings.step_size))
        while t < stop:
            h = min(h, stop - t)
            end = stop if stop - t - h < h_min * (1 - 1e-9) else t + h  # no last step shorter than h_min
            taken = end - t
            smallest = taken <= h_min * (1 + 1e-9)  # end - t rounds: h_min may come out a little larger
            self.at = (len(done.times), t)
            saved = [fmu.call(fmu.instance.getFMUState) for fmu in fmus]
            try:
                try:
                    self.exchange.step(self, t, taken, end)
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
                    for fmu, state in zip(fmus, saved):
                        fmu.call(fmu.instance.setFMUState, state)
            finally:
                for fmu, state in zip(fmus, saved):
                    fmu.call(fmu.instance.freeFMUState, state)
            h = next_step(taken, error, tolerance, order, h_min, h_max)
        return done
