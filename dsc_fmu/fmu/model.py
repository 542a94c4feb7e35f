"""What a slave holds: the interface of one FMU's model, free of FMI (docs/fmus.md, "The Python slave").

Bundled into every FMU; imports only the standard library and ``models``.
"""

from __future__ import annotations

import math

from ..models.rk4 import rk4_integrate, substeps

__all__ = []  # ``Model``, the interface of docs/fmus.md, is subclassed in ``fmu``


class Model:
    """One FMU's variables and equations; ``fmu.slave.ModelSlave`` holds one and does the FMI part.

    A model keeps its parameters ``p`` (set by the slave, which calls ``parameters_changed`` after
    each change) and what it derives from them (``constants``); the slave keeps the inputs, the
    state and the time and hands them to the equations. In every hook, ``t`` is a time in s, ``x`` a
    state in the order of ``STATES``, ``u`` the inputs in the order of ``INPUTS`` (None while the model
    waits for valid inputs), and ``math`` the namespace every equation takes its math from: the module,
    or ``models.dual.DUAL_MATH`` with duals in ``x`` and ``u`` for directional derivatives
    (docs/model.md §5.13).

    The tables (``models.parameters``, ``models.states``): ``PARAMETERS``, ``INPUTS``, ``OUTPUTS``,
    ``STATES`` (the entries of the state vector), ``LOCALS`` (the states' variables that are not
    outputs), ``INDICATORS`` (event indicators), ``FMU_STATE``: the model's own attributes saved in the
    FMU state beside the slave's, each with the function that copies it (also out of JSON), and
    ``BRANCHES``: the switches to hold (``held``) while the build searches the dependencies of ModelStructure.

    What the controller adds has a hook here that does nothing for the other models: waiting for
    valid inputs (``may_wait``, ``waited``; ``u`` None), the start of a step and its end (the beta
    guard: ``before_step``, ``after_step``, ``event``), its own integrator (``substep_count``,
    ``integrate``), parameters that must go together (``conflict``), a state reset at events
    (``reinit``: the projection) and discrete outputs (``discrete_outputs``). A hook that returns a str
    returns a warning for the slave to log; None logs nothing.
    """

    description = ""
    PARAMETERS: tuple = ()
    INPUTS: tuple = ()
    OUTPUTS: tuple = ()
    STATES: tuple = ()
    LOCALS: tuple = ()
    INDICATORS: tuple = ()
    FMU_STATE: dict = {}
    # The switches held (model exchange) whose branches the build's dependency search covers besides those chosen
    # at each point: None alone for a model without switches.
    BRANCHES: tuple = (None,)
    # The Real outputs the model keeps as bookkeeping of its steps rather than computes from the state: not traced
    # to C (docs/traced-c.md), read from ``bookkeeping``.
    UNTRACED_OUTPUTS: tuple = ()

    def __init__(self):
        self.p = {v.name: v.start for v in self.PARAMETERS}
        self._constants = None

    @property
    def constants(self):
        """``derive(p)``, computed once per change of the parameters."""
        if self._constants is None:
            self._constants = self.derive(self.p)
        return self._constants

    def parameters_changed(self) -> None:
        """Forget ``constants``: called by the slave after every change of ``p``."""
        self._constants = None

    def derive(self, p: dict):
        """What the equations need from the parameters ``p`` (by name), precomputed once per change (``constants``):
        ``p`` itself by default."""
        return p

    def initial_state(self, u: list | None, math=math) -> list:
        """The state before the first step, from the parameters and the inputs."""
        raise NotImplementedError

    def rates(self, t: float, x: list, u: list, math=math) -> list:
        """The state's time derivative, free of side effects."""
        raise NotImplementedError

    def outputs(self, t: float, x: list, u: list | None, math=math) -> list:
        """The Real outputs in the order of ``OUTPUTS``, in their units."""
        raise NotImplementedError

    def indicators(self, x: list, u: list, math=math) -> list:
        """The event indicators of model exchange, one per entry of ``INDICATORS``: none by default."""
        return []

    def substep_count(self, step_size: float) -> int:
        """How many sub-steps ``integrate`` takes over a step; the slave discards a step of more than ``MAX_SUBSTEPS``.
        RK4's sub-steps no longer than ``max_step`` by default (docs/model.md §5.11).
        """
        return substeps(step_size, self.p["max_step"])

    def integrate(self, t: float, x: list, step_size: float, inputs) -> list:
        """The state at ``t + step_size`` from ``x`` at ``t``, the inputs at a time within the step being ``inputs(t)``:
        RK4 in sub-steps of at most ``max_step`` by default.
        """
        rates = self.rates
        return rk4_integrate(lambda t, x: rates(t, x, inputs(t)), t, x, step_size, self.p["max_step"])

    def may_wait(self, started: bool) -> bool:
        """Whether refused inputs make the model wait instead of discarding steps (never by default); ``started``:
        whether the state has left ``initial_state``. While it waits, its steps are taken without integrating,
        and its state and outputs are those of ``initial_state`` and ``outputs`` with ``u`` None.
        """
        return False

    def waited(self, t: float, rejected: dict) -> str | None:
        """A step from ``t`` waited for valid inputs; ``rejected``: why each refused variable was refused, by name."""
        return None

    def before_step(self, t: float, started: bool, rejected: dict) -> str | None:
        """A step from ``t`` begins (the model does not wait); with values ``rejected`` (as in ``waited``) it is then
        discarded."""
        return None

    def after_step(self) -> str | None:
        """The step that ``before_step`` began ended, taken or discarded."""
        return None

    def conflict(self) -> str | None:
        """Why the parameters do not go together, or None (checked at the end of initialization)."""
        return None

    def reinit(self, x: list) -> list | None:
        """Model exchange, event mode: the continuous state after the event, or None where it stays ``x``."""
        return None

    def event(self, t: float, x: list, u: list) -> str | None:
        """Model exchange, event mode: choose the switches held until the next event, at the state ``x`` after
        ``reinit``."""
        return None

    def traced_ready(self) -> bool:
        """Whether steps and evaluations may run in the C traced from this model (docs/traced-c.md): whether nothing
        of its bookkeeping would change in a step in which its watch (the beta guard, the drivers' limit) stays quiet.
        """
        return True

    def held_values(self) -> list | None:
        """The switches held (``held``, model exchange) as the traced C takes them (``s``), or None: none held."""
        return None

    def bookkeeping(self) -> list:
        """The values of ``UNTRACED_OUTPUTS``, unchanged by steps and evaluations while ``traced_ready``."""
        return []

    def discrete_outputs(self, slave) -> list:
        """The integer and Boolean outputs, registered after those of the tables: ``(name, description, boolean,
        getter)`` of each, none by default. The getters may read the ``slave`` (``state``, ``u``, ``current_state``,
        ``waiting``).
        """
        return []
