"""FMI 2.0: the slave on pythonfmu, which every FMI 2.0 FMU carries (and no FMI 3.0 FMU needs)."""

from pythonfmu import Boolean, DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

from .slave import FmiLibrary, ModelSlave

__all__ = ["Fmi2ModelSlave"]

PYTHONFMU = FmiLibrary(
    float=Real, integer=Integer, boolean=Boolean, causality=Fmi2Causality, variability=Fmi2Variability,
    initial=Fmi2Initial, status=Fmi2Status, default_experiment=DefaultExperiment, parameter_initial=None,
    independent_time=False,
)


class Fmi2ModelSlave(ModelSlave, Fmi2Slave):
    """``ModelSlave`` on pythonfmu's ``Fmi2Slave``: the base of the FMI 2.0 slave scripts.

    Parameters
    ----------
    model : fmu.model.Model
        The model the slave holds.
    **kwargs
        What ``Fmi2Slave`` takes: ``instance_name``, ``resources``, ``visible``.
    """

    library = PYTHONFMU
