"""MobileRobot.fmu (FMI 2.0): the electrically driven differential-drive robot of docs/model.md §1 (equations 1-8)."""

from dsc_fmu.fmu.fmi2 import Fmi2ModelSlave
from dsc_fmu.fmu.robot_models import MobileRobotModel


class MobileRobot(Fmi2ModelSlave):
    """A ``MobileRobotModel`` in the FMI 2.0 slave (pythonfmu)."""

    def __init__(self, **kwargs):
        super().__init__(MobileRobotModel(), **kwargs)
