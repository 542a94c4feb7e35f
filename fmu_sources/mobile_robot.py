"""MobileRobot.fmu (FMI 2.0): the electrically driven differential-drive robot of docs/model.md §1 (equations 1-8)."""

from dsc_fmu.fmu.fmi2 import DscSlave
from dsc_fmu.fmu.slave_models import MobileRobotModel


class MobileRobot(MobileRobotModel, DscSlave):
    """The FMI 2.0 slave: ``MobileRobotModel`` on the FMI 2.0 glue (pythonfmu)."""

    def __init__(self, **kwargs):
        # pythonfmu 0.7.0 drops a reference to this module that it does not own when an instance is
        # freed; a function defined here keeps the module's namespace alive for the next instance.
        super().__init__(**kwargs)
