"""ReferenceRobot.fmu (FMI 3.0): the reference robot of docs/model.md §2 (equation 9) with its velocity profile."""

from dsc_fmu.fmu.fmi3 import Fmi3ModelSlave
from dsc_fmu.fmu.robot_models import ReferenceRobotModel


class ReferenceRobot(Fmi3ModelSlave):
    """A ``ReferenceRobotModel`` in the FMI 3.0 slave (pythonfmu3)."""

    def __init__(self, **kwargs):
        super().__init__(ReferenceRobotModel(), **kwargs)
