"""One slave glue over FMI 2.0 and 3.0: ``SlaveCore`` registered through an FMI library's names.

Bundled into every FMU beside ``slave_core``, ``slave_models`` and ``models``; imports only the standard
library, ``slave_core`` and ``models``. The FMI library comes as a table of its names (``FmiLibrary``): ``fmi2`` makes it from
pythonfmu, ``fmi3`` from pythonfmu3, and an FMU carries the one module of its FMI version.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..models.parameters import DEFAULT_TOLERANCE
from .slave_core import SlaveCore

__all__ = ["FmiLibrary", "SlaveGlue"]


@dataclass(frozen=True)
class FmiLibrary:
    """The names of an FMI library (pythonfmu or pythonfmu3) that the glue uses, and how the versions differ.

    Parameters
    ----------
    float : type
        The variable class of 64-bit reals (``Real``, ``Float64``).
    integer : type
        The variable class of integers (``Integer``, ``Int32``).
    boolean : type
        The variable class of Booleans.
    causality : type
        The enumeration of causalities.
    variability : type
        The enumeration of variabilities.
    initial : type
        The enumeration of ``initial`` attributes.
    status : type
        The enumeration of statuses, logged with each message.
    default_experiment : type
        The class of the default experiment.
    parameter_initial : object
        The ``initial`` of parameters: None (FMI 2.0 writes none) or ``initial.exact`` (FMI 3.0).
    independent_time : bool
        Whether the FMI version requires the independent variable ``time`` (FMI 3.0).
    """

    float: type
    integer: type
    boolean: type
    causality: type
    variability: type
    initial: type
    status: type
    default_experiment: type
    parameter_initial: object
    independent_time: bool


def _ignore(value) -> None:
    """The setter of a variable that is not set: keeps the FMI library from making one that writes an attribute."""


class SlaveGlue(SlaveCore):
    """``SlaveCore`` registered with the FMI library of ``library``, logging with its statuses.

    A class of ``fmi2`` or ``fmi3`` puts it on that library's slave class (whose ``log`` the core calls)
    and gives ``library``.
    Values are refused without raising, as in ``SlaveCore``; the project's binary resets by
    constructing the slave anew.

    Parameters
    ----------
    **kwargs
        What the FMI library's slave class takes: ``instance_name``, ``resources``, ``visible``.
    """

    library: FmiLibrary

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        library = self.library
        # The FMI library's __init__ sets these to None on the instance.
        self.description = type(self).description
        self.author = "dsc-fmu"
        self.default_experiment = library.default_experiment(start_time=0.0, stop_time=30.0, step_size=1e-3,
                                                             tolerance=DEFAULT_TOLERANCE)
        if library.independent_time:
            self.register_variable(library.float(
                "time", causality=library.causality.independent, variability=library.variability.continuous,
                description="Simulation time", getter=lambda: self.time, setter=_ignore,
            ))
        self._init_core()

    def _register(self, v, causality, getter, setter=None):
        library = self.library
        if causality == "parameter":
            variability = library.variability.tunable if v.tunable else library.variability.fixed
            self.register_variable((library.integer if v.integer else library.float)(
                v.name, causality=library.causality.parameter, variability=variability,
                initial=library.parameter_initial, description=v.description, getter=getter, setter=setter,
            ))
        elif causality == "input":
            self.register_variable(library.float(
                v.name, causality=library.causality.input, variability=library.variability.continuous,
                description=v.description, getter=getter, setter=setter,
            ))
        else:
            self.register_variable(library.float(
                v.name, causality=library.causality[causality], variability=library.variability.continuous,
                initial=library.initial.calculated, description=v.description, getter=getter,
                setter=setter or _ignore,
            ))

    def register_discrete_output(self, name: str, description: str, getter, boolean: bool) -> None:
        """Register a discrete integer (or Boolean) output that ``getter`` computes.

        Parameters
        ----------
        name : str
            The variable's name.
        description : str
            Its description in the model description.
        getter : callable
            Computes its value, without arguments.
        boolean : bool
            Whether it is a Boolean (else an integer: ``Integer``, ``Int32``).
        """
        library = self.library
        self.register_variable((library.boolean if boolean else library.integer)(
            name, causality=library.causality.output, variability=library.variability.discrete,
            initial=library.initial.calculated, description=description, getter=getter, setter=_ignore,
        ))

    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        """Start at ``start_time`` (fmi2SetupExperiment, fmi3EnterInitializationMode).

        Parameters
        ----------
        start_time : float
            The start time, in s.
        stop_time : float or None, optional
            The stop time in s, if defined (FMI 2.0); unused.
        tolerance : float or None, optional
            The tolerance, if defined (FMI 2.0); unused.
        """
        self.time = start_time
        self._stale()
