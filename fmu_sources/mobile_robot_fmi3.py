"""MobileRobot.fmu (FMI 3.0): the electrically driven differential-drive robot of docs/model.md §1 (equations 1-8)."""

from dsc_fmu.fmu.fmi3 import DscSlave
from dsc_fmu.fmu.slave_models import MobileRobotModel


class MobileRobot(MobileRobotModel, DscSlave):
    """``MobileRobotModel`` on the FMI 3.0 glue (pythonfmu3)."""
