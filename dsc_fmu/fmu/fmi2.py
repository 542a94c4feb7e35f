"""The FMI 2.0 plumbing shared by the three slaves: ``SlaveCore`` on pythonfmu's ``Fmi2Slave``.

Bundled into every FMI 2.0 FMU beside ``slave_core``, ``slave_models`` and ``models``; imports only pythonfmu
(which the FMU carries) and the standard library.
"""

from pythonfmu import Boolean, DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

from .slave_core import SlaveCore

__all__ = ["DscSlave"]


class DscSlave(SlaveCore, Fmi2Slave):
    """A co-simulation slave whose model is ``x_dot = derivatives(t, x)`` with held inputs.

    Everything but the FMI 2.0 registration and logging is in ``SlaveCore``: a value outside its
    allowed range is refused without raising, logged as an error, and every ``do_step`` returns
    fmi2Discard until a valid value is set. (The project's binary turns an exception into fmi2Error
    or fmi2Discard.)
    """

    author = "dsc-fmu"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=30.0, step_size=1e-3)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._init_core()

    def _register(self, v, causality, getter, setter=None):
        if causality == "parameter":
            kind = Integer if v.integer else Real
            variability = Fmi2Variability.tunable if v.tunable else Fmi2Variability.fixed
            self.register_variable(kind(
                v.name, causality=Fmi2Causality.parameter, variability=variability,
                description=v.description, getter=getter, setter=setter,
            ))
        elif causality == "input":
            self.register_variable(Real(
                v.name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                description=v.description, getter=getter, setter=setter,
            ))
        else:
            self.register_variable(Real(
                v.name, causality=Fmi2Causality[causality], variability=Fmi2Variability.continuous,
                initial=Fmi2Initial.calculated, description=v.description, getter=getter,
            ))

    def register_discrete_output(self, name, description, getter, boolean):
        """Register a discrete Integer (or Boolean) output that ``getter`` computes."""
        self.register_variable((Boolean if boolean else Integer)(
            name, causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
            initial=Fmi2Initial.calculated, description=description, getter=getter,
        ))

    def log_error(self, message):
        self.log(message, Fmi2Status.error)

    def log_discard(self, message):
        self.log(message, Fmi2Status.discard)

    def log_warning(self, message):
        self.log(message, Fmi2Status.warning)

    def setup_experiment(self, start_time, stop_time, tolerance):
        self.time = start_time
