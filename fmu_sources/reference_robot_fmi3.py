"""ReferenceRobot.fmu, FMI 3.0: the reference robot of SPEC 2 (equation 9), as ``reference_robot.py`` for FMI 2.0."""

from pythonfmu3 import Fmi3Slave

from dsc_fmu.fmi3_slave import DscSlave
from dsc_fmu.models.parameters import REFERENCE_OUTPUTS, REFERENCE_PARAMETERS
from dsc_fmu.models.reference import initial_reference_state, reference_derivatives, velocity


class ReferenceRobot(DscSlave, Fmi3Slave):
    """No inputs. Outputs: reference pose, vr, wr and vr_dot at the current time."""

    description = "Reference robot of the tracking problem (equation 9): constant or figure-eight profile"
    PARAMETERS = REFERENCE_PARAMETERS
    OUTPUTS = REFERENCE_OUTPUTS

    def initial_state(self):
        return initial_reference_state(self.p)

    def derivatives(self, t, x):
        return reference_derivatives(self.p, t, x)

    def outputs(self, x):
        return [*x, *velocity(self.p, self.time)]
