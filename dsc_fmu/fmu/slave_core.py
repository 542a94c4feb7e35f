"""The FMI-version-independent part of the slaves: variables from tables, checks, steps, model exchange, state.

Bundled into every FMU beside ``models``; imports only the standard library, ``models`` and ``jacobian``
(the directional derivatives it inherits).
``glue.SlaveGlue`` puts it on the FMI library's slave class (``fmi2``: pythonfmu, ``fmi3``:
pythonfmu3), which supplies ``log(msg, status, category=None)``; the glue supplies the hook ``_register``
and ``library``, whose ``status`` names the statuses ``log`` takes.
"""

from __future__ import annotations

import math

from ..models.parameters import INPUT_COUPLINGS
from ..models.rk4 import MAX_SUBSTEPS, rk4_integrate, substeps
from .jacobian import DirectionalDerivatives

__all__ = ["SlaveCore"]

HOLD, INTERPOLATE = INPUT_COUPLINGS.index("hold"), INPUT_COUPLINGS.index("interpolate")


def _optional_list(value):
    return None if value is None else list(value)


def _history(value):
    return None if value is None else [value[0], list(value[1])]


def _by_index(value):
    """Input derivatives by input index (JSON gives the indices back as strings)."""
    return {int(index): slope for index, slope in value.items()}


class SlaveCore(DirectionalDerivatives):
    """A slave whose model is ``x_dot = derivatives(t, x)``: co-simulation with held inputs, or model exchange.

    Subclasses give the variable tables (``PARAMETERS``, ``INPUTS``, ``OUTPUTS``) and
    ``initial_state``, ``derivatives`` and ``outputs``. Until the first step, the state is
    ``initial_state()`` of the current parameters and inputs; the first ``do_step`` starts from it
    and integrates with RK4 in sub-steps no longer than the parameter ``max_step`` (at most
    ``MAX_SUBSTEPS`` per step). Over a step the model sees ``inputs(t)``: the inputs set, held, or,
    with the parameter ``coupling``, a line through them and those of the previous step (its
    ``history``, part of the FMU state).

    A value outside its allowed range is refused without raising, so that the set call succeeds and
    the importer can correct it: the refusal is logged as an error naming the variable and its
    range, the variable keeps its last valid value, and every ``do_step`` returns False
    (fmiDiscard) until a valid value is set. Messages go through the FMI library's
    ``log(msg, status)`` with a status of ``library.status``.

    The FMU state (``_get_fmu_state``, ``_set_fmu_state``) is the attributes that ``FMU_STATE``
    names; a model with more state extends the table. The outputs and ``constants`` are cached;
    ``_stale`` says what they are computed from and is called at every change of it.

    The same slave serves model exchange (docs/model-exchange.md): the binary hands it the time and
    the states the importer sets (``set_point``) and reads the vectors of ``STATES`` (derivatives,
    states, nominals) and of ``INDICATORS``; from the end of initialization (``start_continuous_time``)
    the state no longer follows the inputs, and the switches of the model change only in
    ``update_discrete_states``. The tables ``STATES``, ``LOCALS`` and ``INDICATORS`` register the
    states that are not outputs, the states' derivatives and the event indicators as local variables. A
    state's variable sets its entry of the state vector (``set_state``), where the binary allows it.

    ``directional_derivative`` and ``adjoint_derivative`` give products with the Jacobian of the
    unknowns (state derivatives, outputs) with respect to the knowns (states, inputs) by value
    reference: the hooks ``rates``, ``outputs`` and ``state_at`` evaluated on dual numbers
    (``models.dual``), exact to rounding, at the switches the active branch's (docs/model.md §5.13).
    """

    PARAMETERS: tuple = ()
    INPUTS: tuple = ()
    OUTPUTS: tuple = ()
    STATES: tuple = ()  # models.states.ContinuousState of each entry of the state vector
    LOCALS: tuple = ()  # the states' variables that are not outputs
    INDICATORS: tuple = ()  # the variables of ``indicator_values``
    # The FMU state: each attribute saved and restored, and the function that copies its value (also
    # out of a JSON round trip).
    FMU_STATE = {"p": dict, "u": list, "time": float, "rejected": dict, "state": _optional_list, "history": _history,
                 "derivatives_given": _by_index}

    def _init_core(self) -> None:
        """Set up the values and register every variable of the tables (call from ``__init__``)."""
        self.p = {v.name: v.start for v in self.PARAMETERS}
        self.u = [v.start for v in self.INPUTS]
        self._input_index = {v.name: i for i, v in enumerate(self.INPUTS)}
        self.state = None
        self.history = None  # [time, inputs] of the inputs of the last step, stamped as ``coupling`` reads them
        self._slope = None
        self._stamp = 0.0
        self.derivatives_given = {}  # input index -> first derivative for the next step (fmi2SetRealInputDerivatives)
        self.rejected = {}
        self.time = 0.0
        self._roles = None  # value reference -> {role: index}, for directional derivatives (``jacobian``)
        self._resolved = {}  # (value references, model exchange, unknown) -> their (role, index)
        self._stale(parameters=True)
        for v in self.PARAMETERS:
            self._register(v, "parameter", getter=lambda n=v.name: self.p[n],
                           setter=lambda value, v=v: self._set_parameter(v, value))
        for index, v in enumerate(self.INPUTS):
            self._register(v, "input", getter=lambda i=index: self.u[i],
                           setter=lambda value, i=index, v=v: self._set_input(i, v, value))
        positions = {s.variable.name: i for i, s in enumerate(self.STATES)}
        for index, v in enumerate(self.OUTPUTS):
            self._register(v, "output", getter=lambda i=index: self.output_values()[i],
                           setter=self._state_setter(positions.get(v.name)))
        for v in self.LOCALS:
            self._register(v, "local", getter=lambda i=positions[v.name]: self.current_state()[i],
                           setter=self._state_setter(positions[v.name]))
        for index, s in enumerate(self.STATES):
            self._register(s.derivative, "local", getter=lambda i=index: self.get_derivatives()[i])
        for index, v in enumerate(self.INDICATORS):
            self._register(v, "local", getter=lambda i=index: self.get_event_indicators()[i])

    def _register(self, v, causality: str, getter, setter=None) -> None:
        """Hook: register the table variable ``v`` with the FMI library as a ``causality`` ("parameter",
        "input", "output" or "local") variable; an output or local with a ``setter`` is a continuous state."""
        raise NotImplementedError

    def _state_setter(self, index):
        """The setter of entry ``index`` of the state vector (None: no entry, no setter)."""
        return None if index is None else lambda value: self.set_state(index, value)

    def _stale(self, parameters: bool = False) -> None:
        """Forget the caches: called by every change of what they are computed from.

        ``output_values`` is computed from the state, the inputs, the time, the parameters, the values
        refused and the model's switches; ``constants`` from the parameters.

        Parameters
        ----------
        parameters : bool, optional
            Whether the parameters changed (then ``constants`` too is computed again).
        """
        self._cache = None
        if parameters:
            self._constants = None

    def _accept(self, kind: str, v, value) -> bool:
        """Whether ``value`` is allowed for ``v``; if not, log why and hold the FMU until it is."""
        reason = v.check(value)
        if reason is None:
            if self.rejected:
                self.rejected.pop(v.name, None)
            return True
        self.rejected[v.name] = f"{kind} {reason}; allowed: {v.allowed}; the value is refused"
        self._stale()
        self.report_refusal(kind, self.rejected[v.name])
        return False

    def report_refusal(self, kind: str, message: str) -> None:
        """Log the refusal of a value as an error.

        Parameters
        ----------
        kind : {"parameter", "input"}
            What was refused.
        message : str
            Why, naming the variable, the value and the allowed range.
        """
        self.log(f"{self.instance_name}: {message}", self.library.status.error)

    def _set_parameter(self, v, value):
        if self._accept("parameter", v, value):
            self.p[v.name] = int(value) if v.integer else float(value)
            self._stale(parameters=True)

    def _set_input(self, index, v, value):
        if self._accept("input", v, value):
            self.u[index] = float(value)
            self._stale()

    @property
    def constants(self):
        """``derive(p)`` of the current parameters, computed once per change of a parameter."""
        if self._constants is None:
            self._constants = self.derive(self.p)
        return self._constants

    def current_state(self) -> list:
        """The state, also before the first step.

        Until the first step it is ``initial_state()`` of the current parameters and inputs, so the order in
        which an importer initialises, sets and reads does not matter.

        Returns
        -------
        list of float
            The state vector, in the order of ``STATES``.
        """
        return self.initial_state() if self.state is None else self.state

    def substep_count(self, step_size: float) -> int:
        """How many sub-steps ``integrate`` takes over ``step_size``.

        Parameters
        ----------
        step_size : float
            The communication step, in s.

        Returns
        -------
        int
            The number of RK4 sub-steps no longer than ``max_step`` (docs/model.md §5.11).
        """
        return substeps(step_size, self.p["max_step"])

    def too_many_substeps(self, current_time: float, step_size: float) -> bool:
        """Whether the step needs more than ``MAX_SUBSTEPS`` sub-steps: no step may demand unbounded work.

        Parameters
        ----------
        current_time : float
            The communication point the step starts from, in s.
        step_size : float
            The communication step, in s.

        Returns
        -------
        bool
            True if it does (then logged as the reason of a discard).
        """
        n = self.substep_count(step_size)
        if n <= MAX_SUBSTEPS:
            return False
        self.log(
            f"{self.instance_name}: the step of {step_size} s from t = {current_time} s needs {n} sub-steps of at most "
            f"max_step = {self.p['max_step']} s; allowed: at most {MAX_SUBSTEPS} per step; the step is discarded",
            self.library.status.discard,
        )
        return True

    def inputs(self, t: float) -> list:
        """The inputs at ``t`` within the current step: held, or on the line of ``coupling`` (docs/model.md §5.10).

        Parameters
        ----------
        t : float
            A time within the current step, in s.

        Returns
        -------
        list of float
            The inputs in the order of ``INPUTS``, in their units.
        """
        if self._slope is None:
            return self.u
        dt = t - self._stamp
        return [value + dt * slope for value, slope in zip(self.u, self._slope)]

    def set_input_derivatives(self, refs: list, orders: list, values: list) -> None:
        """Take first derivatives of Real inputs for the next step only (fmi2SetRealInputDerivatives).

        Parameters
        ----------
        refs : sequence of int
            The inputs' value references.
        orders : sequence of int
            The derivatives' orders: 1 only.
        values : sequence of float
            The derivatives, in the inputs' units per s.

        Raises
        ------
        ValueError
            If a reference is not a Real input, an order is not 1 or a value is not finite (fmi2Error);
            then none of them is taken.
        """
        given = {}
        for vr, order, value in zip(refs, orders, values):
            index = self._input_index.get(getattr(self.vars.get(int(vr)), "name", None))
            if index is None:
                raise ValueError(f"value reference {int(vr)} is not a Real input")
            if order != 1:
                raise ValueError(f"derivative order {int(order)} of {self.INPUTS[index].name} is not allowed; allowed: 1")
            if not math.isfinite(value):
                raise ValueError(f"the derivative of {self.INPUTS[index].name} is {value}; allowed: finite")
            given[index] = float(value)
        self.derivatives_given.update(given)

    def _ramp(self, current_time: float, step_size: float) -> float:
        """Set the line of the inputs over the step from ``current_time`` and return the time the
        inputs set belong to: the step's end with ``coupling`` = interpolate, else its start. Hold,
        the first step, or a previous step not before this one: no line. Input derivatives given
        for the step (``set_input_derivatives``) take precedence: the line through the inputs set,
        at the step's start, with those slopes (0 for inputs without one)."""
        if self.derivatives_given:
            self._slope = [self.derivatives_given.get(i, 0.0) for i in range(len(self.u))]
            self._stamp = current_time
            return current_time
        coupling = self.p.get("coupling", HOLD)
        stamp = current_time + step_size if coupling == INTERPOLATE else current_time
        self._slope, self._stamp = None, stamp
        if coupling != HOLD and self.history is not None and stamp > self.history[0]:
            since, before = self.history
            self._slope = [(now - then) / (stamp - since) for now, then in zip(self.u, before)]
        return stamp

    def integrate(self, t: float, x: list, step_size: float) -> list:
        """The state after ``step_size`` from ``x`` at ``t``: RK4 in sub-steps of at most ``max_step``.

        Parameters
        ----------
        t : float
            The start time, in s.
        x : list of float
            The state at ``t``.
        step_size : float
            The communication step, in s.

        Returns
        -------
        list of float
            The state at ``t + step_size``.
        """
        return rk4_integrate(self.derivatives, t, x, step_size, self.p["max_step"])

    def output_values(self) -> list:
        """The outputs, computed once per change of state or input.

        Returns
        -------
        list of float
            The outputs in the order of ``OUTPUTS``, in their units.
        """
        if self._cache is None:
            self._cache = self.outputs(self.current_state())
        return self._cache

    def exit_initialization_mode(self):
        """The end of initialization: the outputs are computed again."""
        self._stale()

    def do_step(self, current_time, step_size):
        """Take the communication step (fmi2DoStep, fmi3DoStep).

        Parameters
        ----------
        current_time : float
            The communication point the step starts from, in s.
        step_size : float
            The communication step, in s.

        Returns
        -------
        bool
            True if taken; False (fmiDiscard, the reason logged) while values are refused, for a step of
            more than ``MAX_SUBSTEPS`` sub-steps or a state that is not finite, and then the state is unchanged.
        """
        if self.rejected:
            self.log(
                f"{self.instance_name}: no step while values are refused: {'; '.join(self.rejected.values())}; "
                "the step is discarded", self.library.status.discard,
            )
            return False
        if self.too_many_substeps(current_time, step_size):
            return False
        stamp = self._ramp(current_time, step_size)
        try:
            new = self.integrate(current_time, self.current_state(), step_size)
        finally:
            self._slope = None
        if not all(math.isfinite(value) for value in new):
            self.log(
                f"{self.instance_name}: state not finite after the step from t = {current_time} s "
                f"of {step_size} s; the step is discarded", self.library.status.discard,
            )
            return False
        self.state = new
        self.history = [stamp, list(self.u)]
        self._stepped(current_time + step_size)
        return True

    def _stepped(self, end_time: float) -> None:
        """A step taken up to ``end_time``: its input derivatives used up, the outputs to compute again."""
        self.derivatives_given = {}
        self.time = end_time
        self._stale()

    # --- model exchange: the importer integrates the state; the switches change only at events ---

    def set_point(self, t: float | None, x: list | None) -> None:
        """Take the time and the continuous states that a model-exchange importer set.

        Parameters
        ----------
        t : float or None
            The time in s, unless None.
        x : list of float or None
            The continuous states (copied), unless None.
        """
        if t is not None:
            self.time = t
        if x is not None:
            self.state = list(x)
        self._stale()

    def set_state(self, index: int, value: float) -> None:
        """Set one continuous state, as ``set_point`` sets them all.

        Model exchange: fmi2SetReal or fmi3SetFloat64 of a state in event or continuous-time mode (the
        binary refuses it elsewhere).

        Parameters
        ----------
        index : int
            The state's position in ``STATES``.
        value : float
            Its new value, in its unit.
        """
        state = list(self.current_state())
        state[index] = float(value)
        self.set_point(None, state)

    def get_continuous_states(self) -> list:
        """The continuous states, for model exchange.

        Returns
        -------
        list of float
            A copy of the state, in the order of ``STATES``.
        """
        return list(self.current_state())

    def get_derivatives(self) -> list:
        """The state's time derivative at the current time, inputs and state, for model exchange.

        Returns
        -------
        list of float
            The derivative, in the order of ``STATES``.

        Raises
        ------
        RuntimeError
            While values are refused (fmiDiscard).
        """
        if self.rejected:
            raise RuntimeError(f"no derivatives while values are refused: {'; '.join(self.rejected.values())}")
        return self.derivatives(self.time, self.current_state())

    def get_event_indicators(self) -> list:
        """The event indicators at the current state, for model exchange.

        Returns
        -------
        list of float
            ``indicator_values`` of the state, in the order of ``INDICATORS``.
        """
        return self.indicator_values(self.current_state())

    def get_nominals(self) -> list:
        """The nominal magnitudes of the continuous states, for model exchange.

        Returns
        -------
        list of float
            In the order of ``STATES``, in their units.
        """
        return [s.nominal for s in self.STATES]

    def start_continuous_time(self) -> None:
        """End initialization in model exchange: the state no longer follows the inputs.

        The switches are chosen for the first continuous stretch (``update_discrete_states``).
        """
        if self.state is None:
            self.state = self.initial_state()
        self.update_discrete_states()

    def update_discrete_states(self) -> None:
        """Event mode: choose the switches held until the next event."""
        self._stale()

    def indicator_values(self, x: list) -> list:
        """Hook: the event indicators at state ``x`` (none by default).

        Parameters
        ----------
        x : list of float
            A state.

        Returns
        -------
        list of float
            One value per entry of ``INDICATORS``.
        """
        return []

    def _get_fmu_state(self):
        return {name: copy(getattr(self, name)) for name, copy in self.FMU_STATE.items()}

    def _set_fmu_state(self, saved):
        for name, copy in self.FMU_STATE.items():
            setattr(self, name, copy(saved[name]))
        self._stale(parameters=True)

    def derive(self, p: dict):
        """What the model needs from the parameters ``p``, precomputed (``constants``).

        Parameters
        ----------
        p : dict
            The parameter values by name.

        Returns
        -------
        object
            ``p`` itself by default.
        """
        return p

    def initial_state(self) -> list:
        """Hook: the state at the start, from the current parameters and inputs.

        Returns
        -------
        list of float
            The state vector, in the order of ``STATES``.
        """
        raise NotImplementedError

    def derivatives(self, t: float, x: list) -> list:
        """Hook: the model's ``x_dot = derivatives(t, x)``, its inputs from ``inputs(t)`` (as ``rates``).

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            A state.

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        raise NotImplementedError

    def rates(self, t: float, x: list, u: list, math=math) -> list:
        """Hook: the time derivative of the state ``x`` at time ``t`` and inputs ``u``, free of side effects.

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            A state.
        u : list of float
            The inputs, in the order of ``INPUTS``.
        math : namespace, optional
            The ``math`` module, or ``models.dual.DUAL_MATH`` with duals in ``x`` and ``u``.

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        raise NotImplementedError

    def outputs(self, x: list, u: list | None = None, math=math) -> list:
        """Hook: the outputs at state ``x``, inputs ``u`` and the current time.

        Parameters
        ----------
        x : list of float
            A state.
        u : list of float or None, optional
            The inputs, in the order of ``INPUTS``. Default None: those set.
        math : namespace, optional
            The ``math`` module, or ``models.dual.DUAL_MATH`` with duals in ``x`` and ``u``.

        Returns
        -------
        list of float
            The outputs in the order of ``OUTPUTS``.
        """
        raise NotImplementedError

    def state_at(self, u: list, math=math) -> list:
        """The state as a function of the inputs ``u`` (co-simulation): ``current_state()`` by default.

        A model whose state follows its inputs until the first step overrides it.

        Parameters
        ----------
        u : list of float
            The inputs, in the order of ``INPUTS``.
        math : namespace, optional
            The ``math`` module, or ``models.dual.DUAL_MATH`` with duals in ``u``.

        Returns
        -------
        list of float
            The state vector, in the order of ``STATES``.
        """
        return self.current_state()
