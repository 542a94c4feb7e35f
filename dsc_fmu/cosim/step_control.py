"""The error-controlled communication step (docs/co-simulation.md, "Error-controlled step"): each step's
coupling error estimated from the defect of the exchanged voltages, and the next step size from it.

The defect ``E = max |u_k+1 - u_hat_k+1|`` between the controller's ``u_k+1`` and what the coupling assumed
(held, or on the line through the last two points) is of order ``h`` or ``h^2`` (``scenario.Coupling.order``);
the position error it leaves is estimated as ``error_gain * E`` (m/V).

>>> defect((10.0, 20.0), (11.0, 20.5), None, 1e-3, 1e-3)
1.0
>>> defect((10.0, 20.0), (11.0, 21.0), (9.0, 19.0), 1e-3, 1e-3)
0.0
>>> next_step(1e-3, error=1e-6, tolerance=1e-4, order=2, h_min=1e-5, h_max=0.02)
0.004
>>> next_step(1e-3, error=1e-2, tolerance=1e-4, order=2, h_min=1e-5, h_max=0.02)
0.0002
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__: list[str] = []  # the package's own: ControlledSteps, defect, next_step, SAFETY, GROWTH

SAFETY = 0.9
GROWTH = (0.2, 4.0)  # the next step is between these factors of the last one


def defect(u: tuple, u_next: tuple, u_before: tuple | None, h: float, h_before: float) -> float:
    """The largest difference (V) over the components between ``u_next`` at the step's end and what the coupling
    assumed: ``u`` held (``u_before`` None), or the line through ``u_before`` (at ``t - h_before``) and ``u``."""
    if u_before is None:
        return max(abs(b - a) for a, b in zip(u, u_next))
    ratio = h / h_before
    return max(abs(c - (b + ratio * (b - a))) for a, b, c in zip(u_before, u, u_next))


def next_step(h: float, error: float, tolerance: float, order: int, h_min: float, h_max: float) -> float:
    """The next step (s) after a step ``h`` with an estimated ``error`` (m): the one that meets ``tolerance`` with the
    margin ``SAFETY`` if the error goes as ``h**order``, within ``GROWTH`` times ``h`` and ``[h_min, h_max]``."""
    factor = GROWTH[1] if error == 0 else SAFETY * (tolerance / error) ** (1.0 / order)
    return min(h_max, max(h_min, h * min(GROWTH[1], max(GROWTH[0], factor))))


@dataclass
class ControlledSteps:
    """What an error-controlled run did: start (s), size (s) and estimated position error (m) of every accepted
    step, the steps taken again and the ``doStep`` calls of all FMUs."""

    times: list = field(default_factory=list)
    sizes: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    rejected: int = 0
    fmu_steps: int = 0

    def table(self) -> np.ndarray:
        """The accepted steps: ``time`` (s, the start), ``step_size`` (s) and ``estimated_error`` (m)."""
        history = np.zeros(len(self.times), dtype=[(n, np.float64) for n in ("time", "step_size", "estimated_error")])
        history["time"], history["step_size"], history["estimated_error"] = self.times, self.sizes, self.errors
        return history
