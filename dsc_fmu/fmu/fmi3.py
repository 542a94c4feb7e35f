"""FMI 3.0: the slave on pythonfmu3, which every FMI 3.0 FMU carries (and no FMI 2.0 FMU needs)."""

from pythonfmu3 import Boolean, DefaultExperiment, Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Status, Fmi3Variability
from pythonfmu3 import Float64, Int32

from .slave import FmiLibrary, ModelSlave

__all__ = ["Fmi3ModelSlave"]

PYTHONFMU3 = FmiLibrary(
    float=Float64, integer=Int32, boolean=Boolean, causality=Fmi3Causality, variability=Fmi3Variability,
    initial=Fmi3Initial, status=Fmi3Status, default_experiment=DefaultExperiment,
    parameter_initial=Fmi3Initial.exact, independent_time=True,
)


class Fmi3ModelSlave(ModelSlave, Fmi3Slave):
    """``ModelSlave`` on pythonfmu3's ``Fmi3Slave``: the base of the FMI 3.0 slave scripts.

    Its first variable is the independent variable ``time`` that FMI 3.0 requires; the others are those of
    the FMI 2.0 slave (``Float64`` for ``Real``, ``Int32`` for ``Integer``).

    Parameters
    ----------
    model : fmu.model.Model
        The model the slave holds.
    **kwargs
        What ``Fmi3Slave`` takes: ``instance_name``, ``resources``, ``visible``.
    """

    library = PYTHONFMU3
