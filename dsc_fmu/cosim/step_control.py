"""The error-controlled communication step (docs/co-simulation.md, "Error-controlled step"): each step's
coupling error estimated from the defect of the exchanged voltages, and the next step size from it.

Over a step the plant sees ``u`` held (hold coupling) or extrapolated from the last two communication
points (linear). The defect ``E = max |u_k+1 - u_hat_k+1|`` between the controller's actual ``u_k+1`` and
what the coupling assumed is of order ``h`` (hold) or ``h^2`` (linear), ``scenario.Coupling.order``; the
position error it leaves is estimated as ``error_gain * E`` (m/V, a scenario setting measured on the
paper's scenario, see the docs).

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

__all__ = ["SAFETY", "GROWTH", "ControlledSteps", "defect", "next_step"]

SAFETY = 0.9
GROWTH = (0.2, 4.0)  # the next step is between these factors of the last one


def defect(u: tuple, u_next: tuple, u_before: tuple | None, h: float, h_before: float) -> float:
    """The defect of a step: how far ``u`` at its end is from what the coupling assumed.

    Parameters
    ----------
    u : tuple of float
        ``u`` at the step's start ``t``, in V.
    u_next : tuple of float
        ``u`` at its end ``t + h``, in V.
    u_before : tuple of float or None
        ``u`` at ``t - h_before`` for the linear coupling (the line through it and ``u``); None for
        the hold (``u`` held).
    h : float
        The step in s.
    h_before : float
        The step before it in s (unused with ``u_before`` None).

    Returns
    -------
    float
        The largest difference over the components, in V.
    """
    if u_before is None:
        return max(abs(b - a) for a, b in zip(u, u_next))
    ratio = h / h_before
    return max(abs(c - (b + ratio * (b - a))) for a, b, c in zip(u_before, u, u_next))


def next_step(h: float, error: float, tolerance: float, order: int, h_min: float, h_max: float) -> float:
    """The next step size after a step with an estimated error.

    Parameters
    ----------
    h : float
        The step just taken, in s.
    error : float
        Its estimated position error in m.
    tolerance : float
        m.
    order : int
        The coupling's order (``scenario.Coupling.order``): the error goes as ``h**order``.
    h_min, h_max : float
        The allowed range in s.

    Returns
    -------
    float
        The step (s) that would meet the tolerance with the margin ``SAFETY``, within ``GROWTH`` times
        ``h`` and ``[h_min, h_max]``.
    """
    factor = GROWTH[1] if error == 0 else SAFETY * (tolerance / error) ** (1.0 / order)
    return min(h_max, max(h_min, h * min(GROWTH[1], max(GROWTH[0], factor))))


@dataclass
class ControlledSteps:
    """What an error-controlled run did.

    Parameters
    ----------
    times : list of float, optional
        Start of every accepted step, in s.
    sizes : list of float, optional
        Their sizes in s.
    errors : list of float, optional
        Their estimated position errors in m.
    rejected : int, optional
        Steps taken again, smaller.
    fmu_steps : int, optional
        ``doStep`` calls made, each FMU's counted.
    """

    times: list = field(default_factory=list)
    sizes: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    rejected: int = 0
    fmu_steps: int = 0

    def table(self) -> np.ndarray:
        """The accepted steps as a table.

        Returns
        -------
        numpy.ndarray
            Structured: ``time`` (s, the start), ``step_size`` (s) and ``estimated_error`` (m).
        """
        history = np.zeros(len(self.times), dtype=[(n, np.float64) for n in ("time", "step_size", "estimated_error")])
        history["time"], history["step_size"], history["estimated_error"] = self.times, self.sizes, self.errors
        return history
