"""ReferenceRobot.fmu (FMI 2.0): the reference robot of docs/model.md §2 (equation 9) with its velocity profile."""

from dsc_fmu.fmu.fmi2 import Fmi2ModelSlave
from dsc_fmu.fmu.robot_models import ReferenceRobotModel


class ReferenceRobot(Fmi2ModelSlave):
    """A ``ReferenceRobotModel`` in the FMI 2.0 slave (pythonfmu)."""

    def __init__(self, **kwargs):
        super().__init__(ReferenceRobotModel(), **kwargs)
