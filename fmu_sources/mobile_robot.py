"""MobileRobot.fmu: the electrically driven differential-drive robot of SPEC 1 (equations 1-8)."""

from pythonfmu import DefaultExperiment

from dsc_fmu.fmi_slave import DscSlave
from dsc_fmu.models.parameters import PLANT_INPUTS, PLANT_OUTPUTS, PLANT_PARAMETERS
from dsc_fmu.models.plant import initial_plant_state, plant_coefficients, plant_derivatives, theta_dot


class MobileRobot(DscSlave):
    """Inputs: motor voltages u1, u2. Outputs: pose, heading rate, wheel speeds, currents."""

    description = "Differential-drive mobile robot with rigid-body and DC-motor dynamics (Section II)"
    author = "dsc-fmu"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=30.0, step_size=1e-3)
    PARAMETERS = PLANT_PARAMETERS
    INPUTS = PLANT_INPUTS
    OUTPUTS = PLANT_OUTPUTS

    def __init__(self, **kwargs):
        self.k = None
        super().__init__(**kwargs)

    def parameters_changed(self):
        self.k = None

    def coefficients(self):
        if self.k is None:
            self.k = plant_coefficients(self.p)
        return self.k

    def initial_state(self):
        return initial_plant_state(self.p)

    def derivatives(self, t, x):
        return plant_derivatives(self.coefficients(), x, self.u[0], self.u[1])

    def outputs(self, x):
        x_, y, theta, v1, v2, i1, i2 = x
        return [x_, y, theta, theta_dot(self.coefficients(), v1, v2), v1, v2, i1, i2]
