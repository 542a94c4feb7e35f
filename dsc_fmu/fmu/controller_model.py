"""The model of DSCController.fmu: the adaptive dynamic surface controller (docs/model.md §3, equations 10-27).

Bundled into every FMU; imports only the standard library and ``models``.
"""

import math

from ..models.adaptation import PROJECTION, project_estimates, projection_conflict
from ..models.controller import (
    W1_SLICE, W2_SLICE, Switches, control_law, event_indicators, gains, initial_controller_state, start_filters, switches,
    weight_norm,
)
from ..models.parameters import (
    CONTROLLER_INPUTS, CONTROLLER_OUTPUTS, CONTROLLER_PARAMETERS, DISCRETIZATIONS, START_ON,
)
from ..models.rk4 import euler_step, rk4_integrate
from ..models.states import CONTROLLER_STATES, EVENT_INDICATORS, FILTER_STATES
from .model import Model

__all__ = ["DSCControllerModel"]

EULER = DISCRETIZATIONS.index("euler")
VALID_INPUTS = START_ON.index("valid_inputs")
_WAITING_LAW_OUTPUTS = [v.start for v in CONTROLLER_OUTPUTS[:6]]  # u1, u2, S11, S12, S13, beta
_GUARD = "h2 divides by beta_min (outside the region of Remark 3)"


def _switches(held):
    """The held switches (lists after a JSON round trip), or None."""
    return None if held is None else Switches(held[0], held[1], tuple(held[2]))


class DSCControllerModel(Model):
    """Inputs: measurements and reference. Outputs: voltages u1, u2 (direct feedthrough) and internals.

    The 20 states ``xc`` are integrated with RK4 (``discretization`` = rk4) or one explicit Euler step
    per communication step (euler). Before the first step the filters are x2f = x2bar, x3f = x3bar of
    the inputs (docs/model.md §5.2). The outputs are the voltages (26), the surfaces (10), (12), beta
    (13), the estimates and their norms; the event indicators ``[cos((thetar - theta) / 2), beta -
    beta_min]`` change sign at the wrap and the guard. The beta guard (§5.6) is counted
    (``beta_guard_count``: steps in which an evaluation was guarded; in model exchange, events at which
    it engages), shown (``beta_guard_active``) and logged at the first step of each run of such steps;
    in model exchange the switches are held between events (``held``, §5.13).

    With ``adaptation`` = projection the estimates stay in their sets (docs/model.md §5.13): co-simulation
    moves them back onto the sets after each sub-step, model exchange at each event (``reinit``), where
    it reports that the continuous states changed. Parameters that make no projection (an interval's
    ``min`` not below its ``max``, an initial estimate outside its set) fail the end of initialization.

    With ``start_on`` = valid_inputs, a controller that has not started and whose only refused values
    are inputs waits instead of discarding its steps: u = 0, S11 = S12 = S13 = 0, beta = 1, estimates
    at their initial values, ``started`` False. It starts at the first step at which every input is
    valid; both ends of the wait are logged as warnings.
    """

    description = "Adaptive dynamic surface controller for the electrically driven mobile robot (Section III)"
    PARAMETERS = CONTROLLER_PARAMETERS
    INPUTS = CONTROLLER_INPUTS
    OUTPUTS = CONTROLLER_OUTPUTS
    STATES = CONTROLLER_STATES
    LOCALS = FILTER_STATES
    INDICATORS = EVENT_INDICATORS
    FMU_STATE = {"beta_guard_count": int, "_guarded_last_step": bool, "waited_steps": int, "held": _switches}
    # The projection acting on every estimate: a branch whose dependencies the others' do not cover.
    BRANCHES = (None, Switches(0, False, (True, True, True, True)))

    def __init__(self):
        super().__init__()
        self.held = None  # model exchange: the switches held since the last event; None: chosen at each evaluation
        self.beta_guard_count = 0
        self.waited_steps = 0
        self._guarded_last_step = False
        self._guard_seen = None  # (t, beta) of the first evaluation of the step with the guard acting

    def derive(self, p):
        return gains(p)

    def initial_state(self, u, math=math):
        if u is None:
            return initial_controller_state(self.p)
        return start_filters(self.constants, initial_controller_state(self.p), u, math)

    def rates(self, t, x, u, math=math):
        return control_law(self.constants, x, u, self.held, math).derivative

    def outputs(self, t, x, u, math=math):
        W1_hat, W2_hat = x[W1_SLICE], x[W2_SLICE]
        estimates = [x[0], x[1], weight_norm(W1_hat, math), weight_norm(W2_hat, math), *W1_hat, *W2_hat]
        if u is None:
            return [*_WAITING_LAW_OUTPUTS, *estimates]
        law = control_law(self.constants, x, u, self.held, math)
        return [law.u1, law.u2, law.S11, law.S12, law.S13, law.beta, *estimates]

    def indicators(self, x, u, math=math):
        return event_indicators(self.constants, x, u, self.held, math)

    def substep_count(self, step_size):
        return 1 if self.p["discretization"] == EULER else super().substep_count(step_size)

    def integrate(self, t, x, step_size, inputs):
        c, held = self.constants, self.held

        def derivatives(t, x):
            law = control_law(c, x, inputs(t), held, math)
            if law.guarded and self._guard_seen is None:
                self._guard_seen = (t, law.beta)
            return law.derivative

        project = (lambda x: project_estimates(c, x)) if c.adaptation == PROJECTION else None
        if self.p["discretization"] == EULER:
            x = euler_step(derivatives, t, x, step_size)
            return x if project is None else project(x)
        return rk4_integrate(derivatives, t, x, step_size, self.p["max_step"], project)

    def may_wait(self, started):
        return not started and self.p["start_on"] == VALID_INPUTS

    def waited(self, t, rejected):
        self.waited_steps += 1
        if self.waited_steps == 1:
            return (f"waits for valid inputs from t = {t:.6g} s with u = 0 (start_on = valid_inputs): "
                    f"{'; '.join(rejected.values())}")
        return None

    def before_step(self, t, started, rejected):
        self._guard_seen = None
        if not started and self.waited_steps and not rejected:
            return (f"every input valid at t = {t:.6g} s: the controller starts after waiting {self.waited_steps} "
                    "step(s) with u = 0 (start_on = valid_inputs)")
        return None

    def after_step(self):
        seen, guarded_before = self._guard_seen, self._guarded_last_step
        self._guarded_last_step = seen is not None
        if seen is None:
            return None
        self.beta_guard_count += 1
        if guarded_before:
            return None
        t, beta = seen
        return f"beta = {beta:.6g} < beta_min = {self.p['beta_min']:g} at t = {t:.6g} s: {_GUARD}"

    def conflict(self):
        return projection_conflict(self.p)

    def reinit(self, x):
        if self.constants.adaptation != PROJECTION:
            return None
        projected = project_estimates(self.constants, x)
        return None if projected is x else projected

    def event(self, t, x, u):
        held = switches(self.constants, x, u)
        engages = held.guarded and not (self.held and self.held.guarded)
        self.held = held
        if engages:
            self.beta_guard_count += 1
            return f"beta < beta_min = {self.p['beta_min']:g} from t = {t:.6g} s: {_GUARD}"
        return None

    def traced_ready(self):
        return self.p["discretization"] != EULER and not self._guarded_last_step

    def held_values(self):
        held = self.held
        return None if held is None else [float(held.turns), float(held.guarded), *map(float, held.projected)]

    def discrete_outputs(self, slave):
        def law():
            if slave.waiting():
                return None
            return control_law(self.constants, slave.current_state(), slave.u, self.held)

        def guarded():
            now = law()
            return bool(now and now.guarded)

        def projecting():
            now = law()
            return bool(now and any(now.projected))

        return [
            ("beta_guard_count", "Number of steps in which beta fell below beta_min and the guard acted "
             "(docs/model.md §5)", False, lambda: self.beta_guard_count),
            ("beta_guard_active", "True while beta < beta_min at the current inputs and state", True, guarded),
            ("projection_active", "True while the projection acts on an estimate at the current inputs and state "
             "(adaptation = projection: docs/model.md §3, §5.13)", True, projecting),
            ("started", "True once the filter states have started (docs/model.md §5); False while initialising and "
             "while the controller waits for valid inputs (start_on = valid_inputs)", True,
             lambda: slave.state is not None),
        ]
