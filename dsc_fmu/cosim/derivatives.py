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

__all__ = ["InputRamps"]


def _slope(now: list, before: list, dt: float) -> list:
    return [(a - b) / dt for a, b in zip(now, before)]


class InputRamps:
    """The values of the last two exchanges, and the input derivatives set from them.

    Parameters
    ----------
    plant : fmpy.fmi2.FMU2Slave
        The plant's instance.
    plant_u : list of int
        Value references of its inputs ``u1, u2``.
    controller : fmpy.fmi2.FMU2Slave
        The controller's instance.
    controller_in : list of int
        Value references of its measured inputs.
    jacobi : bool
        Jacobi (the controller's slopes extrapolate) rather than Gauss-Seidel (they interpolate).
    """

    def __init__(self, plant, plant_u: list, controller, controller_in: list, jacobi: bool):
        self.plant, self.plant_u = plant, plant_u
        self.controller, self.controller_in = controller, controller_in
        self.jacobi = jacobi
        self.at = self.u = self.measured = None
        self.before = None  # (time, u, measurements) of the exchange before the last

    def exchanged(self, at: float, u: list, measured: list) -> None:
        """Note an exchange.

        Parameters
        ----------
        at : float
            Its time in s.
        u : list of float
            The voltages set on the plant, in V.
        measured : list of float
            The measurements set on the controller.
        """
        if self.at is not None:
            self.before = (self.at, self.u, self.measured)
        self.at, self.u, self.measured = at, list(u), list(measured)

    def before_plant(self) -> None:
        """The plant's slope of ``u`` for the step from the last exchange (none at the first)."""
        if self.before is not None:
            self.plant.setRealInputDerivatives(self.plant_u, [1] * len(self.plant_u),
                                               _slope(self.u, self.before[1], self.at - self.before[0]))

    def before_controller(self, step: float, measured_end: list) -> None:
        """Set the controller's slopes for the step from the last exchange.

        Parameters
        ----------
        step : float
            The step's size in s.
        measured_end : list of float
            The measurements at the step's end (Gauss-Seidel interpolates towards them).
        """
        if self.jacobi:
            if self.before is None:
                return
            slopes = _slope(self.measured, self.before[2], self.at - self.before[0])
        else:
            slopes = _slope(measured_end, self.measured, step)
        self.controller.setRealInputDerivatives(self.controller_in, [1] * len(self.controller_in), slopes)
