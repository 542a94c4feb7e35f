"""The FMI 3.0 plumbing shared by the three slaves: ``SlaveCore`` on pythonfmu3's ``Fmi3Slave``.

Bundled into every FMI 3.0 FMU beside ``slave_core``, ``slave_models`` and ``models``; imports only pythonfmu3
(which the FMU carries) and the standard library.
"""

from pythonfmu3 import DefaultExperiment, Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Status, Fmi3Variability
from pythonfmu3 import Boolean, Float64, Int32

from .slave_core import SlaveCore

__all__ = ["DscSlave"]


class DscSlave(SlaveCore, Fmi3Slave):
    """``SlaveCore`` as an FMI 3.0 co-simulation slave (pythonfmu3).

    The same variables as the FMI 2.0 slave (Float64 for Real, Int32 for Integer), after the
    independent variable ``time`` that FMI 3.0 requires. The project's binary resets by
    constructing the slave anew and passes the start time of fmi3EnterInitializationMode to
    ``setup_experiment``; values are refused without raising, as in ``SlaveCore``.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        # Fmi3SlaveBase.__init__ sets these to None on the instance: take the class's values.
        self.description = type(self).description
        self.author = "dsc-fmu"
        self.default_experiment = DefaultExperiment(start_time=0.0, stop_time=30.0, step_size=1e-3)
        self.register_variable(Float64(
            "time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous,
            description="Simulation time", getter=lambda: self.time, setter=lambda value: None,
        ))
        self._init_core()

    def _register(self, v, causality, getter, setter=None):
        if causality == "parameter":
            kind = Int32 if v.integer else Float64
            variability = Fmi3Variability.tunable if v.tunable else Fmi3Variability.fixed
            self.register_variable(kind(
                v.name, causality=Fmi3Causality.parameter, variability=variability,
                initial=Fmi3Initial.exact, description=v.description, getter=getter, setter=setter,
            ))
        elif causality == "input":
            self.register_variable(Float64(
                v.name, causality=Fmi3Causality.input, variability=Fmi3Variability.continuous,
                description=v.description, getter=getter, setter=setter,
            ))
        else:
            self.register_variable(Float64(
                v.name, causality=Fmi3Causality[causality], variability=Fmi3Variability.continuous,
                initial=Fmi3Initial.calculated, description=v.description, getter=getter,
                setter=lambda value: None,
            ))

    def register_discrete_output(self, name, description, getter, boolean):
        """Register a discrete Int32 (or Boolean) output that ``getter`` computes."""
        self.register_variable((Boolean if boolean else Int32)(
            name, causality=Fmi3Causality.output, variability=Fmi3Variability.discrete,
            initial=Fmi3Initial.calculated, description=description, getter=getter, setter=lambda value: None,
        ))

    def log_error(self, message):
        self.log(message, Fmi3Status.error)

    def log_discard(self, message):
        self.log(message, Fmi3Status.discard)

    def log_warning(self, message):
        self.log(message, Fmi3Status.warning)

    def setup_experiment(self, start_time):
        self.time = start_time
