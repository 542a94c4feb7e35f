"""The models of MobileRobot.fmu (docs/model.md §1) and ReferenceRobot.fmu (§2).

Bundled into every FMU; imports only the standard library and ``models``.
"""

import math

from ..models.parameters import (
    DRIVE_OUTPUTS, PLANT_INPUTS, PLANT_OUTPUTS, PLANT_PARAMETERS, REFERENCE_OUTPUTS, REFERENCE_PARAMETERS,
)
from ..models.plant import (
    FREE, HIGH, UNLIMITED, applied_voltages, initial_plant_state, plant_coefficients, plant_derivatives, saturation,
    saturation_indicators, theta_dot,
)
from ..models.reference import initial_reference_state, reference_derivatives, velocity
from ..models.rk4 import rk4_integrate
from ..models.states import PLANT_EVENT_INDICATORS, PLANT_STATES, REFERENCE_STATES
from .model import Model

__all__ = ["MobileRobotModel", "ReferenceRobotModel"]


def _optional_tuple(value):
    """The held switches (a list after a JSON round trip), or None."""
    return None if value is None else tuple(value)


def _optional_float(value):
    return None if value is None else float(value)


class MobileRobotModel(Model):
    """Inputs: motor voltages u1, u2. Outputs: pose, rates, currents (eqs. 1-8), the drivers' voltages and limit.

    State ``[x, y, theta, v1, v2, i1, i2]`` in m, m, rad, rad/s, rad/s, A, A; ``constants`` are
    ``models.plant.plant_coefficients``. After the currents the outputs are the voltages the drivers apply and
    how long they limited them. With ``voltage_limit`` = on, each driver applies ``clip(u_j, -u_max_j,
    u_max_j)`` (docs/model.md §5.14): chosen at each evaluation in co-simulation, held between events in model
    exchange (``held``, §5.13), where the event indicators ``u_max_j -+ u_j`` change sign at each switch. How often
    the limit acted, ``saturation_count``: in co-simulation the steps in which it acted after a step in which it did
    not, in model exchange the events at which it engaged (either motor, both interfaces). How long,
    ``saturation_time``: in co-simulation each step's length times the share of its evaluations (the RK4 stages) at
    which either input was beyond its limit; in model exchange the time from each event that engaged it to the one
    that released it (or to now).
    """

    description = "Differential-drive mobile robot with rigid-body and DC-motor dynamics (Section II)"
    PARAMETERS = PLANT_PARAMETERS
    INPUTS = PLANT_INPUTS
    OUTPUTS = (*PLANT_OUTPUTS, *DRIVE_OUTPUTS)
    STATES = PLANT_STATES
    INDICATORS = PLANT_EVENT_INDICATORS
    BRANCHES = (None, (HIGH, HIGH))  # the drivers limited: what u_max1, u_max2 reach
    FMU_STATE = {"held": _optional_tuple, "saturation_count": int, "saturation_time": float,
                 "_limited_last_step": bool, "_limited_since": _optional_float}
    UNTRACED_OUTPUTS = ("saturation_time",)

    def __init__(self):
        super().__init__()
        self.held = None  # model exchange: the drivers' switches held since the last event; None: chosen at each call
        self.saturation_count = 0
        self.saturation_time = 0.0  # s, up to the last step or (model exchange) the last event
        self._limited_last_step = False
        self._limited_since = None  # model exchange: the time of the event that engaged the limit

    def derive(self, p):
        return plant_coefficients(p)

    def initial_state(self, u, math=math):
        return initial_plant_state(self.p)

    def rates(self, t, x, u, math=math):
        return plant_derivatives(self.constants, t, x, u[0], u[1], math, self.held)

    def outputs(self, t, x, u, math=math):
        k = self.constants
        x_, y, theta, v1, v2, i1, i2 = x
        since = self._limited_since
        limited = self.saturation_time if since is None else self.saturation_time + (t - since)
        applied = applied_voltages(k, u[0], u[1], self.held)
        return [x_, y, theta, theta_dot(k, v1, v2), v1, v2, i1, i2, *applied, limited]

    def indicators(self, x, u, math=math):
        return saturation_indicators(self.constants, u[0], u[1])

    def integrate(self, t, x, step_size, inputs):
        k = self.constants
        if k.u_max is None:
            return super().integrate(t, x, step_size, inputs)
        evaluations = [0, 0]  # all, with an input beyond its limit

        def rates(t, x):
            u1, u2 = inputs(t)
            switches = saturation(k, u1, u2)
            evaluations[0] += 1
            evaluations[1] += switches != UNLIMITED
            return plant_derivatives(k, t, x, u1, u2, math, switches)

        new = rk4_integrate(rates, t, x, step_size, self.p["max_step"])
        limited = evaluations[1] > 0
        self.saturation_count += limited and not self._limited_last_step
        self.saturation_time += step_size * evaluations[1] / evaluations[0]
        self._limited_last_step = limited
        return new

    def event(self, t, x, u):
        held = saturation(self.constants, u[0], u[1])
        if held != UNLIMITED and self._limited_since is None:
            self.saturation_count += 1
            self._limited_since = t
        elif held == UNLIMITED and self._limited_since is not None:
            self.saturation_time += t - self._limited_since
            self._limited_since = None
        self.held = held
        return None

    def traced_ready(self):
        return not self._limited_last_step and self._limited_since is None

    def held_values(self):
        return None if self.held is None else [float(switch) for switch in self.held]

    def bookkeeping(self):
        return [self.saturation_time]

    def discrete_outputs(self, slave):
        def active():
            switches = saturation(self.constants, *slave.u) if self.held is None else self.held
            return any(switch != FREE for switch in switches)

        return [
            ("saturation_count", "How often the voltage limit engaged: the steps in which either driver limited its "
             "voltage after a step in which none did; in model exchange, the events at which it engaged (docs/model.md "
             "§5.14)", False, lambda: self.saturation_count),
            ("saturation_active", "True while either driver limits its voltage at the current inputs (in model "
             "exchange, as held since the last event)", True, active),
        ]


class ReferenceRobotModel(Model):
    """No inputs. Outputs: reference pose, vr, wr and vr_dot at the time (equation 9 and its profile).

    State ``[xr, yr, thetar]`` in m, m, rad.
    """

    description = "Reference robot of the tracking problem (equation 9): constant or figure-eight profile"
    PARAMETERS = REFERENCE_PARAMETERS
    OUTPUTS = REFERENCE_OUTPUTS
    STATES = REFERENCE_STATES

    def initial_state(self, u, math=math):
        return initial_reference_state(self.p)

    def rates(self, t, x, u, math=math):
        return reference_derivatives(self.p, t, x, math)

    def outputs(self, t, x, u, math=math):
        return [*x, *velocity(self.p, t, math)]
