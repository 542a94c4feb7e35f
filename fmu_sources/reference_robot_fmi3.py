"""ReferenceRobot.fmu (FMI 3.0): the reference robot of docs/model.md §2 (equation 9) with its velocity profile."""

from pythonfmu3 import Fmi3Slave

from dsc_fmu.fmu.fmi3 import DscSlave
from dsc_fmu.fmu.slave_models import ReferenceRobotModel


class ReferenceRobot(ReferenceRobotModel, DscSlave, Fmi3Slave):
    """The FMI 3.0 slave: ``ReferenceRobotModel`` on the FMI 3.0 glue (pythonfmu3)."""
