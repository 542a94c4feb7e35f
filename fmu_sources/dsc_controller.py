"""DSCController.fmu (FMI 2.0): the adaptive dynamic surface controller of docs/model.md §3 (equations 10-27)."""

from dsc_fmu.fmu.fmi2 import Fmi2ModelSlave
from dsc_fmu.fmu.controller_model import DSCControllerModel


class DSCController(Fmi2ModelSlave):
    """A ``DSCControllerModel`` in the FMI 2.0 slave (pythonfmu)."""

    def __init__(self, **kwargs):
        super().__init__(DSCControllerModel(), **kwargs)
