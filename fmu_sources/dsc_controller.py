"""DSCController.fmu (FMI 2.0): the adaptive dynamic surface controller of docs/model.md §3 (equations 10-27)."""

from dsc_fmu.fmu.fmi2 import DscSlave
from dsc_fmu.fmu.slave_models import DSCControllerModel


class DSCController(DSCControllerModel, DscSlave):
    """``DSCControllerModel`` on the FMI 2.0 glue (pythonfmu)."""
