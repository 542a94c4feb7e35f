"""DSCController.fmu (FMI 3.0): the adaptive dynamic surface controller of docs/model.md §3 (equations 10-27)."""

from dsc_fmu.fmu.fmi3 import Fmi3ModelSlave
from dsc_fmu.fmu.controller_model import DSCControllerModel


class DSCController(Fmi3ModelSlave):
    """A ``DSCControllerModel`` in the FMI 3.0 slave (pythonfmu3)."""

    def __init__(self, **kwargs):
        super().__init__(DSCControllerModel(), **kwargs)
