"""MobileRobot.fmu, FMI 3.0: the robot of SPEC 1 (equations 1-8), as ``mobile_robot.py`` for FMI 2.0."""

from pythonfmu3 import Fmi3Slave

from dsc_fmu.fmi3_slave import DscSlave
from dsc_fmu.models.parameters import PLANT_INPUTS, PLANT_OUTPUTS, PLANT_PARAMETERS
from dsc_fmu.models.plant import initial_plant_state, plant_coefficients, plant_derivatives, theta_dot


class MobileRobot(DscSlave, Fmi3Slave):
    """Inputs: motor voltages u1, u2. Outputs: pose, heading rate, wheel speeds, currents."""

    description = "Differential-drive mobile robot with rigid-body and DC-motor dynamics (Section II)"
    PARAMETERS = PLANT_PARAMETERS
    INPUTS = PLANT_INPUTS
    OUTPUTS = PLANT_OUTPUTS

    def derive(self, p):
        return plant_coefficients(p)

    def initial_state(self):
        return initial_plant_state(self.p)

    def derivatives(self, t, x):
        return plant_derivatives(self.constants, x, self.u[0], self.u[1])

    def outputs(self, x):
        x_, y, theta, v1, v2, i1, i2 = x
        return [x_, y, theta, theta_dot(self.constants, v1, v2), v1, v2, i1, i2]
