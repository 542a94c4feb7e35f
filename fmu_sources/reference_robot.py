"""ReferenceRobot.fmu: the reference robot of SPEC 2 (equation 9) with its velocity profile."""

from dsc_fmu.fmi_slave import DscSlave
from dsc_fmu.models.parameters import REFERENCE_OUTPUTS, REFERENCE_PARAMETERS
from dsc_fmu.models.reference import initial_reference_state, reference_derivatives, velocity


class ReferenceRobot(DscSlave):
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
