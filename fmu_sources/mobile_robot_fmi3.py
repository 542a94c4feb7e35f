"""MobileRobot.fmu (FMI 3.0): the electrically driven differential-drive robot of docs/model.md §1 (equations 1-8)."""

from dsc_fmu.fmu.fmi3 import Fmi3ModelSlave
from dsc_fmu.fmu.robot_models import MobileRobotModel


class MobileRobot(Fmi3ModelSlave):
    """A ``MobileRobotModel`` in the FMI 3.0 slave (pythonfmu3)."""

    def __init__(self, **kwargs):
        super().__init__(MobileRobotModel(), **kwargs)
