"""The models of MobileRobot.fmu (docs/model.md §1) and ReferenceRobot.fmu (§2).

Bundled into every FMU; imports only the standard library and ``models``.
"""

import math

from ..models.parameters import PLANT_INPUTS, PLANT_OUTPUTS, PLANT_PARAMETERS, REFERENCE_OUTPUTS, REFERENCE_PARAMETERS
from ..models.plant import initial_plant_state, plant_coefficients, plant_derivatives, theta_dot
from ..models.reference import initial_reference_state, reference_derivatives, velocity
from ..models.states import PLANT_STATES, REFERENCE_STATES
from .model import Model

__all__ = ["MobileRobotModel", "ReferenceRobotModel"]


class MobileRobotModel(Model):
    """Inputs: motor voltages u1, u2. Outputs: pose, heading rate, wheel speeds, currents (equations 1-8).

    State ``[x, y, theta, v1, v2, i1, i2]`` in m, m, rad, rad/s, rad/s, A, A; ``constants`` are
    ``models.plant.plant_coefficients``.
    """

    description = "Differential-drive mobile robot with rigid-body and DC-motor dynamics (Section II)"
    PARAMETERS = PLANT_PARAMETERS
    INPUTS = PLANT_INPUTS
    OUTPUTS = PLANT_OUTPUTS
    STATES = PLANT_STATES

    def derive(self, p):
        return plant_coefficients(p)

    def initial_state(self, u, math=math):
        return initial_plant_state(self.p)

    def rates(self, t, x, u, math=math):
        return plant_derivatives(self.constants, x, u[0], u[1], math)

    def outputs(self, t, x, u, math=math):
        x_, y, theta, v1, v2, i1, i2 = x
        return [x_, y, theta, theta_dot(self.constants, v1, v2), v1, v2, i1, i2]


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
        return [*x, *velocity(self.p, t)]
