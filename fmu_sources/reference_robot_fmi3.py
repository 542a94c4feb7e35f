"""ReferenceRobot.fmu (FMI 3.0): the reference robot of docs/model.md §2 (equation 9) with its velocity profile."""

from dsc_fmu.fmu.fmi3 import DscSlave
from dsc_fmu.fmu.slave_models import ReferenceRobotModel


class ReferenceRobot(ReferenceRobotModel, DscSlave):
    """``ReferenceRobotModel`` on the FMI 3.0 glue (pythonfmu3)."""
