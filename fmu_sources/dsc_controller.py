"""DSCController.fmu (FMI 2.0): the adaptive dynamic surface controller of docs/model.md §3 (equations 10-27)."""

from dsc_fmu.fmu.fmi2 import DscSlave
from dsc_fmu.fmu.slave_models import DSCControllerModel


class DSCController(DSCControllerModel, DscSlave):
    """The FMI 2.0 slave: ``DSCControllerModel`` on the FMI 2.0 glue (pythonfmu)."""

    def __init__(self, **kwargs):
        # pythonfmu 0.7.0 drops a reference to this module that it does not own when an instance is
        # freed; a function defined here keeps the module's namespace alive for the next instance.
        super().__init__(**kwargs)
