"""The slave of every FMU: holds a ``model.Model`` and does the FMI part, for FMI 2.0 (``fmi2``) and 3.0 (``fmi3``).

Bundled into every FMU; imports only the standard library and ``models`` (docs/fmus.md, "The Python slave").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..models.dual import DUAL_MATH, tangent
from ..models.parameters import ANY, DEFAULT_TOLERANCE, INPUT_COUPLINGS, NONNEGATIVE, POSITIVE, TRACED
from ..models.rk4 import MAX_SUBSTEPS
from .directional import DERIVATIVE, INPUT, OUTPUT, STATE, Roles, adjoint, directional, seeded

__all__ = []  # ``fmi2`` and ``fmi3`` use ``FmiLibrary`` and ``ModelSlave``

HOLD, INTERPOLATE = INPUT_COUPLINGS.index("hold"), INPUT_COUPLINGS.index("interpolate")
TRACED_ON = TRACED.index("on")
# The roles of the variables the binary reads or sets in C (``traced_layout``), and the bounds of its inputs' check.
PARAMETER, INPUT_VALUE, TRACED_OUTPUT, BOOKKEEPING_OUTPUT, STATE_VALUE, STATE_DERIVATIVE = range(6)
BOUNDS = {ANY: 0, NONNEGATIVE: 1, POSITIVE: 2}


@dataclass(frozen=True)
class FmiLibrary:
    """The names of an FMI library (pythonfmu or pythonfmu3) the slave uses, and how the versions differ:
    ``parameter_initial`` is None for FMI 2.0 (no ``initial`` on parameters), ``initial.exact`` for 3.0;
    ``independent_time`` whether the version requires the variable ``time`` (3.0).
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


def _optional_list(value):
    return None if value is None else list(value)


def _history(value):
    return None if value is None else [value[0], list(value[1])]


def _by_index(value):
    """Input derivatives by input index (JSON gives the indices back as strings)."""
    return {int(index): slope for index, slope in value.items()}


class ModelSlave:
    """A slave that holds ``model`` (a ``model.Model``) and maps the FMI calls onto it: co-simulation or model exchange.

    ``fmi2.Fmi2ModelSlave`` and ``fmi3.Fmi3ModelSlave`` put it on the FMI library's slave class, which
    supplies ``log(msg, status)`` and the value getters and setters; ``library`` names the library.

    Until the first step the state is the model's ``initial_state`` of the current parameters and
    inputs, whatever the order in which an importer sets and reads. A step (``do_step``) integrates the
    model with its ``integrate`` (RK4 in sub-steps no longer than ``max_step``, at most
    ``MAX_SUBSTEPS``); over a step the model sees ``inputs(t)``: the inputs held, or, with the parameter
    ``coupling``, on a line through them and those of the previous step (``history``, docs/model.md §5.10).

    A value outside its allowed range is refused without raising, so that the set call succeeds and the
    importer can correct it: the refusal is logged as an error naming the variable and its range, the
    variable keeps its last valid value, and every ``do_step`` returns False (fmiDiscard) until a valid
    value is set; a model that ``may_wait`` waits instead while only inputs are refused.

    The FMU state is the model's parameters, the slave's values of ``_FMU_STATE`` and the model's of
    ``model.FMU_STATE``. The outputs are cached; ``_stale`` is called at every change they depend on.

    Model exchange (docs/model-exchange.md): the binary sets the time and states (``set_point``) and reads
    the vectors of ``model.STATES`` and ``model.INDICATORS``; from the end of initialization the state no
    longer follows the inputs, and the model's switches change only in ``update_discrete_states``.
    Vectors are in the order of ``model.STATES``, ``model.INPUTS``, ``model.OUTPUTS`` or ``model.INDICATORS``.
    """

    library: FmiLibrary
    # The slave's values in the FMU state, after the parameters: the function that copies each (also out of JSON).
    _FMU_STATE = {"u": list, "time": float, "rejected": dict, "state": _optional_list, "history": _history,
                  "derivatives_given": _by_index}

    def __init__(self, model, **kwargs):
        super().__init__(**kwargs)
        library = self.library
        self.model = model
        # The FMI library's __init__ sets these to None on the instance.
        self.description = model.description
        self.author = "dsc-fmu"
        self.default_experiment = library.default_experiment(start_time=0.0, stop_time=30.0, step_size=1e-3,
                                                             tolerance=DEFAULT_TOLERANCE)
        if library.independent_time:
            self.register_variable(library.float(
                "time", causality=library.causality.independent, variability=library.variability.continuous,
                description="Simulation time", getter=lambda: self.time, setter=_ignore,
            ))
        self.u = [v.start for v in model.INPUTS]
        self._input_index = {v.name: i for i, v in enumerate(model.INPUTS)}
        self.state = None
        self.history = None  # [time, inputs] of the last step, stamped as ``coupling`` reads them
        self._slope = None
        self._stamp = 0.0
        self.derivatives_given = {}  # input index -> first derivative for the next step (fmi2SetRealInputDerivatives)
        self.rejected = {}
        self.time = 0.0
        self._stale(parameters=True)
        self._register_tables()
        self._roles = Roles(model, self.vars, type(self).__name__)

    def _register_tables(self) -> None:
        model, library = self.model, self.library
        causality, variability = library.causality, library.variability
        for v in model.PARAMETERS:
            self.register_variable((library.integer if v.integer else library.float)(
                v.name, causality=causality.parameter, variability=variability.tunable if v.tunable else variability.fixed,
                initial=library.parameter_initial, description=v.description, getter=lambda n=v.name: model.p[n],
                setter=lambda value, v=v: self._set_parameter(v, value),
            ))
        for index, v in enumerate(model.INPUTS):
            self.register_variable(library.float(
                v.name, causality=causality.input, variability=variability.continuous, description=v.description,
                getter=lambda i=index: self.u[i], setter=lambda value, i=index, v=v: self._set_input(i, v, value),
            ))

        def calculated(v, kind, getter, setter=None):
            """Register ``v``, computed by ``getter``; an output or local with a ``setter`` is a continuous state."""
            self.register_variable(library.float(
                v.name, causality=kind, variability=variability.continuous, initial=library.initial.calculated,
                description=v.description, getter=getter, setter=setter or _ignore,
            ))

        positions = {s.variable.name: i for i, s in enumerate(model.STATES)}
        for index, v in enumerate(model.OUTPUTS):
            calculated(v, causality.output, lambda i=index: self.output_values()[i], self._state_setter(positions.get(v.name)))
        for v in model.LOCALS:
            calculated(v, causality.local, lambda i=positions[v.name]: self.current_state()[i],
                       self._state_setter(positions[v.name]))
        for index, s in enumerate(model.STATES):
            calculated(s.derivative, causality.local, lambda i=index: self.get_derivatives()[i])
        for index, v in enumerate(model.INDICATORS):
            calculated(v, causality.local, lambda i=index: self.get_event_indicators()[i])
        for name, description, boolean, getter in model.discrete_outputs(self):
            self.register_variable((library.boolean if boolean else library.integer)(
                name, causality=causality.output, variability=variability.discrete,
                initial=library.initial.calculated, description=description, getter=getter, setter=_ignore,
            ))

    def _state_setter(self, index):
        """The setter of entry ``index`` of the state vector (None: no entry, no setter)."""
        return None if index is None else lambda value: self.set_state(index, value)

    def _warn(self, message) -> None:
        if message is not None:
            self.log(f"{self.instance_name}: {message}", self.library.status.warning)

    def _stale(self, parameters: bool = False) -> None:
        """Forget the cached outputs (and with ``parameters`` the model's constants): called at every change
        of the state, inputs, time, parameters, values refused or the model's switches."""
        self._cache = None
        if parameters:
            self.model.parameters_changed()

    # --- values -------------------------------------------------------------------------------------------

    def _accept(self, kind: str, v, value) -> bool:
        """Whether ``value`` is allowed for ``v``; if not, log why (unless the model may wait for it) and hold the FMU
        until it is."""
        reason = v.check(value)
        if reason is None:
            if self.rejected:
                self.rejected.pop(v.name, None)
            return True
        self.rejected[v.name] = f"{kind} {reason}; allowed: {v.allowed}; the value is refused"
        self._stale()
        if kind == "parameter" or not self.model.may_wait(self.state is not None):
            self.log(f"{self.instance_name}: {self.rejected[v.name]}", self.library.status.error)
        return False

    def _set_parameter(self, v, value):
        if self._accept("parameter", v, value):
            self.model.p[v.name] = int(value) if v.integer else float(value)
            self._stale(parameters=True)

    def _set_input(self, index, v, value):
        if self._accept("input", v, value):
            self.u[index] = float(value)
            self._stale()

    def waiting(self) -> bool:
        """Whether the model waits for valid inputs: it ``may_wait`` and the only values refused are inputs."""
        return (bool(self.rejected) and self.model.may_wait(self.state is not None)
                and all(name in self._input_index for name in self.rejected))

    def current_state(self) -> list:
        """The state; before the first step the model's ``initial_state`` of the current parameters and inputs."""
        if self.state is not None:
            return self.state
        return self.model.initial_state(None if self.rejected and self.waiting() else self.u)

    def output_values(self) -> list:
        """The Real outputs, computed once per change of what they depend on."""
        if self._cache is None:
            u = None if self.rejected and self.waiting() else self.u
            self._cache = self.model.outputs(self.time, self.current_state(), u)
        return self._cache

    def inputs(self, t: float) -> list:
        """The inputs at ``t`` (s) within the current step: held, or on the line of ``coupling`` (docs/model.md §5.10)."""
        if self._slope is None:
            return self.u
        dt = t - self._stamp
        return [value + dt * slope for value, slope in zip(self.u, self._slope)]

    def set_input_derivatives(self, refs: list, orders: list, values: list) -> None:
        """Take first derivatives of Real inputs (by value reference, in their units per s) for the next step only
        (fmi2SetRealInputDerivatives); ValueError (fmi2Error), taking none, if a reference is not a Real input, an order
        is not 1 or a value is not finite.
        """
        given = {}
        inputs = self.model.INPUTS
        for vr, order, value in zip(refs, orders, values):
            index = self._input_index.get(getattr(self.vars.get(int(vr)), "name", None))
            if index is None:
                raise ValueError(f"value reference {int(vr)} is not a Real input")
            if order != 1:
                raise ValueError(f"derivative order {int(order)} of {inputs[index].name} is not allowed; allowed: 1")
            if not math.isfinite(value):
                raise ValueError(f"the derivative of {inputs[index].name} is {value}; allowed: finite")
            given[index] = float(value)
        self.derivatives_given.update(given)

    # --- co-simulation ------------------------------------------------------------------------------------

    def setup_experiment(self, start_time: float, stop_time: float | None = None,
                         tolerance: float | None = None) -> None:
        """Start at ``start_time`` (fmi2SetupExperiment, fmi3EnterInitializationMode); FMI 2.0's stop time and tolerance
        are unused."""
        self.time = start_time
        self._stale()

    def exit_initialization_mode(self):
        """The end of initialization: the outputs are computed again. ValueError (fmiError) if the parameters do
        not go together (the model's ``conflict``)."""
        conflict = self.model.conflict()
        if conflict is not None:
            raise ValueError(f"parameters that do not go together: {conflict}")
        self._stale()

    def do_step(self, current_time: float, step_size: float) -> bool:
        """Take the communication step (fmi2DoStep, fmi3DoStep): what one step does is written here.

        True if taken (or waited for valid inputs); False (fmiDiscard, the reason logged) while values are refused,
        for a step of more than ``MAX_SUBSTEPS`` sub-steps or a state that is not finite, and then the state is
        unchanged.
        """
        model = self.model
        if self.rejected and self.waiting():
            self._warn(model.waited(current_time, self.rejected))
            self._stepped(current_time + step_size)
            return True
        self._warn(model.before_step(current_time, self.state is not None, self.rejected))
        n = model.substep_count(step_size)
        if self.rejected:
            why = f"no step while values are refused: {'; '.join(self.rejected.values())}"
        elif n > MAX_SUBSTEPS:
            why = (f"the step of {step_size} s from t = {current_time} s needs {n} sub-steps of at most max_step = "
                   f"{model.p['max_step']} s; allowed: at most {MAX_SUBSTEPS} per step")
        else:
            stamp = self._ramp(current_time, step_size)
            try:
                new = model.integrate(current_time, self.current_state(), step_size, self.inputs)
            finally:
                self._slope = None
            finite = all(map(math.isfinite, new))
            why = None if finite else f"state not finite after the step from t = {current_time} s of {step_size} s"
        if why is None:
            self.state = new
            self.history = [stamp, list(self.u)]
            self._stepped(current_time + step_size)
        else:
            self.log(f"{self.instance_name}: {why}; the step is discarded", self.library.status.discard)
        self._warn(model.after_step())
        return why is None

    def _ramp(self, current_time: float, step_size: float) -> float:
        """Set the line of the inputs over the step and return the time the inputs set belong to: the step's end
        with ``coupling`` = interpolate, else its start. Hold, the first step, or a previous step not before
        this one: no line. Input derivatives given for the step take precedence: the line through the
        inputs set, at the step's start, with those slopes (0 for inputs without one)."""
        if self.derivatives_given:
            self._slope = [self.derivatives_given.get(i, 0.0) for i in range(len(self.u))]
            self._stamp = current_time
            return current_time
        coupling = self.model.p.get("coupling", HOLD)
        stamp = current_time + step_size if coupling == INTERPOLATE else current_time
        self._slope, self._stamp = None, stamp
        if coupling != HOLD and self.history is not None and stamp > self.history[0]:
            since, before = self.history
            self._slope = [(now - then) / (stamp - since) for now, then in zip(self.u, before)]
        return stamp

    def _stepped(self, end_time: float) -> None:
        """A step taken up to ``end_time``: its input derivatives used up, the outputs to compute again."""
        self.derivatives_given = {}
        self.time = end_time
        self._stale()

    # --- model exchange -----------------------------------------------------------------------------------

    def set_point(self, t: float | None, x: list | None) -> None:
        """Take the time (s) and the continuous states (copied) that a model-exchange importer set; None leaves one as
        it is."""
        if t is not None:
            self.time = t
        if x is not None:
            self.state = list(x)
        self._stale()

    def set_state(self, index: int, value: float) -> None:
        """Set state ``index`` as ``set_point`` sets them all (fmi2SetReal, fmi3SetFloat64 where the binary allows)."""
        state = list(self.current_state())
        state[index] = float(value)
        self.set_point(None, state)

    def get_continuous_states(self) -> list:
        """A copy of the continuous states."""
        return list(self.current_state())

    def get_derivatives(self) -> list:
        """The states' time derivatives at the current time, inputs and state; RuntimeError (fmiDiscard) while values
        are refused."""
        if self.rejected:
            raise RuntimeError(f"no derivatives while values are refused: {'; '.join(self.rejected.values())}")
        return self.model.rates(self.time, self.current_state(), self.u)

    def get_event_indicators(self) -> list:
        """The event indicators at the current state and inputs."""
        return self.model.indicators(self.current_state(), self.u)

    def get_nominals(self) -> list:
        """The nominal magnitudes of the continuous states, in their units."""
        return [s.nominal for s in self.model.STATES]

    def start_continuous_time(self) -> None:
        """End initialization in model exchange: the state no longer follows the inputs, the switches are chosen."""
        if self.state is None:
            self.state = self.model.initial_state(self.u)
        self.update_discrete_states()

    def update_discrete_states(self) -> bool:
        """Event mode: the model resets the continuous state (``reinit``) and chooses the switches held until the
        next event; whether the state changed."""
        state = self.model.reinit(self.current_state())
        if state is not None:
            self.state = state
        self._warn(self.model.event(self.time, self.current_state(), self.u))
        self._stale()
        return state is not None

    # --- the traced C (docs/traced-c.md) ----------------------------------------------------------------------

    def traced_layout(self) -> tuple:
        """Where the binary finds what the traced C reads, as three flat lists of numbers: ``(variables, sizes,
        inputs)``.

        ``variables``: value reference, role and index of each parameter (its index in ``p``), input, traced output
        (its index in the traced outputs), output of the model's bookkeeping (``Model.UNTRACED_OUTPUTS``), state and
        state derivative (their index in the state), the roles ``PARAMETER``, ``INPUT_VALUE``, ``TRACED_OUTPUT``,
        ``BOOKKEEPING_OUTPUT``, ``STATE_VALUE``, ``STATE_DERIVATIVE``; ``sizes``: the lengths of
        ``p``, the state, the inputs, the traced outputs and the bookkeeping, the indices of ``max_step`` and
        ``coupling`` in ``p`` (-1: none), ``MAX_SUBSTEPS`` and the codes of hold and interpolate; ``inputs``: each
        input's check, its ``BOUNDS`` code, minimum and maximum.
        """
        model = self.model
        references = {v.name: vr for vr, v in self.vars.items()}
        traced = [v for v in model.OUTPUTS if v.name not in model.UNTRACED_OUTPUTS]
        roles = [
            *((v.name, PARAMETER, i) for i, v in enumerate(model.PARAMETERS)),
            *((v.name, INPUT_VALUE, i) for i, v in enumerate(model.INPUTS)),
            *((v.name, TRACED_OUTPUT, i) for i, v in enumerate(traced)),
            *((name, BOOKKEEPING_OUTPUT, i) for i, name in enumerate(model.UNTRACED_OUTPUTS)),
            *((s.variable.name, STATE_VALUE, i) for i, s in enumerate(model.STATES)),
            *((s.derivative.name, STATE_DERIVATIVE, i) for i, s in enumerate(model.STATES)),
        ]
        names = [v.name for v in model.PARAMETERS]
        sizes = [len(names), len(model.STATES), len(model.INPUTS), len(traced), len(model.UNTRACED_OUTPUTS),
                 *(names.index(name) if name in names else -1 for name in ("max_step", "coupling")),
                 MAX_SUBSTEPS, HOLD, INTERPOLATE]
        inputs = [(BOUNDS[v.bound], -math.inf if v.minimum is None else v.minimum,
                   math.inf if v.maximum is None else v.maximum) for v in model.INPUTS]
        return ([number for name, role, i in roles for number in (references[name], role, i)], sizes,
                [number for check in inputs for number in check])

    def traced_snapshot(self):
        """What the binary needs to step and evaluate the model in C, or None where Python runs: ``traced`` = off,
        values refused, before the first step (the state follows the inputs), input derivatives given, or the model
        not ``traced_ready``.

        ``(p, time, state, inputs, history time, history inputs, held, bookkeeping)``: the parameters in the order
        of ``PARAMETERS``, the slave's time, state and inputs, the last step's stamped inputs (``history``; None,
        None before it), the model's ``held_values`` and ``bookkeeping``.
        """
        model = self.model
        if (model.p["traced"] != TRACED_ON or self.rejected or self.state is None or self.derivatives_given
                or not model.traced_ready()):
            return None
        since, before = self.history or (None, None)
        return list(model.p.values()), self.time, self.state, self.u, since, before, model.held_values(), \
            model.bookkeeping()

    def traced_sync(self, inputs: list, time: float | None, state: list | None, stamp: float | None,
                    stamped: list | None) -> None:
        """Take what the binary did in C since ``traced_snapshot``: the ``inputs`` set, and unless ``time`` is None
        the steps it took, the last ending at ``time`` in ``state`` with the inputs ``stamped`` at ``stamp``."""
        self.u = list(inputs)
        if time is not None:
            self.time, self.state, self.history = time, list(state), [stamp, list(stamped)]
        self._stale()

    # --- FMU state ----------------------------------------------------------------------------------------

    def _get_fmu_state(self):
        model = self.model
        saved = {"p": dict(model.p)}
        saved.update((name, copy(getattr(self, name))) for name, copy in self._FMU_STATE.items())
        saved.update((name, copy(getattr(model, name))) for name, copy in model.FMU_STATE.items())
        return saved

    def _set_fmu_state(self, saved):
        model = self.model
        model.p = dict(saved["p"])
        for name, copy in self._FMU_STATE.items():
            setattr(self, name, copy(saved[name]))
        for name, copy in model.FMU_STATE.items():
            setattr(model, name, copy(saved[name]))
        self._stale(parameters=True)

    # --- directional derivatives --------------------------------------------------------------------------

    def directional_derivative(self, unknowns: list, knowns: list, seed: list, model_exchange: bool) -> list:
        """``J seed``, J the Jacobian of the unknowns by the knowns, by value reference (fmi2/fmi3GetDirectionalDerivative).

        Model exchange: at the time, continuous state and inputs set, with the switches held (docs/model.md
        §5.13); unknowns are state derivatives and Real outputs, knowns continuous states and Real inputs.
        Co-simulation: at the current state and inputs, the switches as the law chooses them there, the state
        following the inputs until the first step (§5.2); unknowns are Real outputs, knowns Real inputs.
        One forward pass on dual numbers. ValueError for a reference that is not an allowed unknown or known,
        or a ``seed`` whose length differs from that of ``knowns``.
        """
        rows, columns = self._roles.resolve(unknowns, model_exchange, True), self._roles.resolve(knowns, model_exchange, False)
        return directional(lambda rows, direction: self._forward(rows, direction, model_exchange), rows, columns, seed)

    def adjoint_derivative(self, unknowns: list, knowns: list, seed: list, model_exchange: bool) -> list:
        """``seed^T J`` (fmi3GetAdjointDerivative), J and errors as in ``directional_derivative``: one forward pass per
        known."""
        rows, columns = self._roles.resolve(unknowns, model_exchange, True), self._roles.resolve(knowns, model_exchange, False)
        return adjoint(lambda rows, direction: self._forward(rows, direction, model_exchange), rows, columns, seed)

    def _forward(self, rows: list, direction: dict, model_exchange: bool) -> list:
        """The tangents of the unknowns ``rows`` ((role, index) pairs) along ``direction`` (role -> {index: seed})."""
        model = self.model
        u = seeded(self.u, direction[INPUT])
        if model_exchange:
            x = seeded(self.current_state(), direction[STATE])
        elif self.state is None and not self.waiting():
            x = model.initial_state(u, DUAL_MATH)  # the state follows the inputs until the first step (§5.2)
        else:
            x = self.current_state()
        roles = {role for role, _ in rows}
        values = {
            DERIVATIVE: model.rates(self.time, x, u, DUAL_MATH) if DERIVATIVE in roles else None,
            OUTPUT: model.outputs(self.time, x, None if self.waiting() else u, DUAL_MATH) if OUTPUT in roles else None,
        }
        return [tangent(values[role][index]) for role, index in rows]
