"""The linear coupling through the standard route: ``fmi2SetRealInputDerivatives`` from the master.

With its FMUs' ``coupling`` parameters left at hold, the master gives each step's slopes itself: the
plant's ``u`` the slope through the last two communication points (extrapolation), the controller's
inputs the slope to the measurements at the step's end (Gauss-Seidel: interpolation; its inputs
stay those of the step's start until the exchange there) or through the last two points (Jacobi:
extrapolation). The plant's first step holds (there is no earlier u), as does the controller's with
Jacobi; with Gauss-Seidel it interpolates from the first step on. FMI 2.0 only: FMI 3.0 has no
input derivatives.
"""

from __future__ import annotations

from .instance import LoadedFmu
from .loop import Exchange, Run

__all__: list[str] = []  # the package's own: InputDerivatives


def _slope(now: list, before: list, dt: float) -> list:
    return [(a - b) / dt for a, b in zip(now, before)]


def _set_slopes(fmu: LoadedFmu, refs: list[int], slopes: list[float]) -> None:
    fmu.call(fmu.instance.setRealInputDerivatives, refs, [1] * len(refs), slopes)


class InputDerivatives(Exchange):
    """Our exchange with the slopes set before each step (the module's rule), Jacobi or Gauss-Seidel."""

    sets_slopes = True

    def __init__(self, jacobi: bool):
        self.jacobi = jacobi
        self.last = None  # (time, u, measurements) of the last exchange
        self.before = None  # and of the one before it

    def _exchanged(self, at: float, u: list, measured: list) -> None:
        if self.last is not None:
            self.before = self.last
        self.last = (at, list(u), list(measured))

    def start(self, run: Run) -> None:
        super().start(run)
        self._exchanged(0.0, run.u, run.wiring.measurements.held)

    def step(self, run: Run, t: float, h: float, end: float) -> None:
        wiring = run.wiring
        at, u, measured_then = self.last
        if self.before is not None:
            _set_slopes(run.plant, wiring.voltages.refs, _slope(u, self.before[1], at - self.before[0]))
        run.reference.do_step(t, h)
        run.plant.do_step(t, h)
        measured = wiring.measurements.read(end, run.bound)
        if not self.jacobi:
            _set_slopes(run.controller, wiring.measurements.refs, _slope(measured, measured_then, h))
        elif self.before is not None:
            _set_slopes(run.controller, wiring.measurements.refs,
                        _slope(measured_then, self.before[2], at - self.before[0]))
        run.controller.do_step(t, h)
        run.stepped(end)
        run.u = wiring.exchange(end, run.bound, measured)
        self._exchanged(end, run.u, measured)
