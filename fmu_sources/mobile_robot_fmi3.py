"""MobileRobot.fmu (FMI 3.0): the electrically driven differential-drive robot of docs/model.md §1 (equations 1-8)."""

from pythonfmu3 import Fmi3Slave

from dsc_fmu.fmu.fmi3 import DscSlave
from dsc_fmu.fmu.slave_models import MobileRobotModel


class MobileRobot(MobileRobotModel, DscSlave, Fmi3Slave):
    """The FMI 3.0 slave: ``MobileRobotModel`` on the FMI 3.0 glue (pythonfmu3)."""
