"""The continuous states of the three models as model exchange exposes them: order, variables, nominals.

Each model's state vector (``plant_derivatives``, ``reference_derivatives``, ``control_law``) is
named here entry by entry, by the FMU variable that holds it. The nominals are the magnitudes the
physics of the paper's robot gives (docs/model.md §4): an importer's solver scales its absolute
tolerances by them.
"""

from dataclasses import dataclass

from .parameters import (
    CONTROLLER_OUTPUTS, PLANT_OUTPUTS, PLANT_PARAMETERS, REFERENCE_OUTPUTS, REFERENCE_PARAMETERS, Variable, defaults,
)
from .plant import plant_coefficients

__all__ = [
    "ContinuousState", "PLANT_STATES", "REFERENCE_STATES", "CONTROLLER_STATES", "FILTER_STATES", "EVENT_INDICATORS",
    "PLANT_EVENT_INDICATORS",
]

# The unit of a quantity's time derivative, for the units of the states.
_PER_SECOND = {"m": "m/s", "rad": "rad/s", "rad/s": "rad/s2", "A": "A/s", "1": "1/s", "1/m": "1/(m.s)"}


@dataclass(frozen=True)
class ContinuousState:
    """One entry of a model's state vector: the variable that holds it and its nominal magnitude.

    Parameters
    ----------
    variable : Variable
        The FMU variable that holds the state (an output, or a local of ``FILTER_STATES``).
    nominal : float
        Its nominal magnitude, in the variable's unit.
    """

    variable: Variable
    nominal: float

    @property
    def derivative(self) -> Variable:
        """The local variable ``der(<name>)`` that holds the state's time derivative."""
        v = self.variable
        return Variable(f"der({v.name})", 0.0, _PER_SECOND[v.unit], f"Time derivative of {v.name}")


def true_unknowns(p: dict) -> tuple:
    """``(a1, a2, W1, W2)`` that the controller's estimates stand for, for the plant parameters ``p``
    (docs/model.md §3): a1 = 1/r in 1/m, a2 = R/r, W1 of (22) and W2 of (27) as tuples."""
    k = plant_coefficients(p)
    W1 = (k.c / k.nkt1, k.c / k.nkt2, k.d11 / k.nkt1, k.d22 / k.nkt2,
          k.m11 / k.nkt1, k.m12 / k.nkt1, k.m11 / k.nkt2, k.m12 / k.nkt2)
    W2 = (k.ra1, k.ra2, k.nke1, k.nke2, k.la1, k.la2)
    return 1.0 / k.r, k.R / k.r, W1, W2


def _states(variables, nominals: dict) -> tuple:
    """A ``ContinuousState`` of each named variable of ``variables``, in the order of ``nominals``."""
    by_name = {v.name: v for v in variables}
    return tuple(ContinuousState(by_name[name], nominal) for name, nominal in nominals.items())


_PLANT = defaults(PLANT_PARAMETERS)
_a1, _a2, _W1, _W2 = true_unknowns(_PLANT)
_SPEED = defaults(REFERENCE_PARAMETERS)["vr0"] * _a1  # wheel speed at the reference's speed, rad/s
_CURRENT = _PLANT["d11"] * _SPEED / (_PLANT["N1"] * _PLANT["KT1"])  # current that holds that speed against damping, A

PLANT_STATES = _states(PLANT_OUTPUTS, {
    "x": 1.0, "y": 1.0, "theta": 1.0, "omega1": _SPEED, "omega2": _SPEED, "i1": _CURRENT, "i2": _CURRENT,
})
"""``[x, y, theta, v1, v2, i1, i2]`` of models/plant.py."""

REFERENCE_STATES = _states(REFERENCE_OUTPUTS, {"x_r": 1.0, "y_r": 1.0, "theta_r": 1.0})
"""``[xr, yr, thetar]`` of models/reference.py."""

FILTER_STATES = (
    Variable("x2f1", 0.0, "rad/s", "Filtered virtual wheel speed x2bar, right wheel (eq. 17)"),
    Variable("x2f2", 0.0, "rad/s", "Filtered virtual wheel speed x2bar, left wheel (eq. 17)"),
    Variable("x3f1", 0.0, "A", "Filtered virtual current x3bar, right wheel (eq. 23)"),
    Variable("x3f2", 0.0, "A", "Filtered virtual current x3bar, left wheel (eq. 23)"),
)
"""The controller's filter states, local variables of the FMU (its other states are outputs)."""

CONTROLLER_STATES = _states((*CONTROLLER_OUTPUTS, *FILTER_STATES), {
    "a1_hat": _a1, "a2_hat": _a2, "x2f1": _SPEED, "x2f2": _SPEED,
    **{f"W1_hat_{i}": abs(w) for i, w in enumerate(_W1, start=1)},
    "x3f1": _CURRENT, "x3f2": _CURRENT,
    **{f"W2_hat_{i}": abs(w) for i, w in enumerate(_W2, start=1)},
})
"""``xc`` of models/controller.py: ``[a1_hat, a2_hat, x2f1, x2f2, W1_hat (8), x3f1, x3f2, W2_hat (6)]``."""

EVENT_INDICATORS = (
    Variable("wrap_indicator", 0.0, "1", "cos((theta_r - theta)/2): changes sign where the wrap of S13bar jumps "
             "(docs/model.md §5.13)"),
    Variable("guard_indicator", 0.0, "1", "beta - beta_min: changes sign where the beta guard switches "
             "(docs/model.md §5.13)"),
    Variable("projection_indicator", 0.0, "1", "The projection's least margin: changes sign where it starts or "
             "stops acting on an estimate (adaptation = projection; 1 for the other laws; docs/model.md §5.13)"),
)
"""The controller's event indicators, in the order of ``controller.event_indicators``."""

PLANT_EVENT_INDICATORS = tuple(
    Variable(f"u{i}_{side}_indicator", 0.0, "V", f"{expression}: changes sign where the {wheel} wheel's driver "
             f"{what} (docs/model.md §5.13; 1 with voltage_limit = off)")
    for i, wheel in ((1, "right"), (2, "left"))
    for side, expression, what in (("upper", f"u_max{i} - u{i}", "saturates at +u_max"),
                                   ("lower", f"u_max{i} + u{i}", "saturates at -u_max"))
)
"""The plant's event indicators, in the order of ``plant.saturation_indicators``."""
