"""FMI 3.0: the slave glue on pythonfmu3, which every FMI 3.0 FMU carries (and no FMI 2.0 FMU needs).

Bundled into every FMI 3.0 FMU beside ``glue``; imports only pythonfmu3 and the standard library.
"""

from pythonfmu3 import Boolean, DefaultExperiment, Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Status, Fmi3Variability
from pythonfmu3 import Float64, Int32

from .glue import FmiLibrary, SlaveGlue

__all__ = ["DscSlave"]

PYTHONFMU3 = FmiLibrary(
    float=Float64, integer=Int32, boolean=Boolean, causality=Fmi3Causality, variability=Fmi3Variability,
    initial=Fmi3Initial, status=Fmi3Status, default_experiment=DefaultExperiment,
    parameter_initial=Fmi3Initial.exact, independent_time=True,
)


class DscSlave(SlaveGlue, Fmi3Slave):
    """``SlaveGlue`` on pythonfmu3's ``Fmi3Slave``: the base of the FMI 3.0 slave scripts.

    Its first variable is the independent variable ``time`` that FMI 3.0 requires; the others are
    those of the FMI 2.0 slave (``Float64`` for ``Real``, ``Int32`` for ``Integer``).

    Parameters
    ----------
    **kwargs
        What ``Fmi3Slave`` takes: ``instance_name``, ``resources``, ``visible``.
    """

    library = PYTHONFMU3
