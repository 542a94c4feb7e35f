"""What each FMU computes, independent of the FMI version: the robot, the reference robot, the controller.

Bundled into every FMU beside ``slave_core`` and ``models``. Each class is a mixin put before the
glue of an FMI version (``fmi2.DscSlave`` or ``fmi3.DscSlave``) in a slave script of
``fmu_sources``; the glue supplies ``register_discrete_output`` and ``library``, the FMI library's slave
class ``log``.
"""

import math

from ..models.controller import (
    W1_SLICE, W2_SLICE, Switches, control_law, event_indicators, gains, initial_controller_state, start_filters, switches,
    weight_norm,
)
from ..models.parameters import (
    CONTROLLER_INPUTS, CONTROLLER_OUTPUTS, CONTROLLER_PARAMETERS, DISCRETIZATIONS, PLANT_INPUTS, PLANT_OUTPUTS,
    PLANT_PARAMETERS, REFERENCE_OUTPUTS, REFERENCE_PARAMETERS, START_ON,
)
from ..models.plant import initial_plant_state, plant_coefficients, plant_derivatives, theta_dot
from ..models.reference import initial_reference_state, reference_derivatives, velocity
from ..models.rk4 import euler_step
from ..models.states import CONTROLLER_STATES, EVENT_INDICATORS, FILTER_STATES, PLANT_STATES, REFERENCE_STATES
from .slave_core import SlaveCore

__all__ = ["MobileRobotModel", "ReferenceRobotModel", "DSCControllerModel"]

EULER = DISCRETIZATIONS.index("euler")
VALID_INPUTS = START_ON.index("valid_inputs")
_INPUT_NAMES = frozenset(v.name for v in CONTROLLER_INPUTS)
_WAITING_LAW_OUTPUTS = [v.start for v in CONTROLLER_OUTPUTS[:6]]  # u1, u2, S11, S12, S13, beta


def _switches(held):
    """The held switches (a list after a JSON round trip), or None."""
    return None if held is None else Switches(*held)


class MobileRobotModel:
    """Inputs: motor voltages u1, u2. Outputs: pose, heading rate, wheel speeds, currents (docs/model.md §1)."""

    description = "Differential-drive mobile robot with rigid-body and DC-motor dynamics (Section II)"
    PARAMETERS = PLANT_PARAMETERS
    INPUTS = PLANT_INPUTS
    OUTPUTS = PLANT_OUTPUTS
    STATES = PLANT_STATES

    def derive(self, p):
        """The constants of (1)-(8) from the parameters ``p``.

        Parameters
        ----------
        p : dict
            The parameter values by name.

        Returns
        -------
        PlantCoefficients
            ``models.plant.plant_coefficients(p)``.
        """
        return plant_coefficients(p)

    def initial_state(self):
        """The plant's state at the start (docs/model.md §5.1).

        Returns
        -------
        list of float
            ``[x, y, theta, v1, v2, i1, i2]`` in m, m, rad, rad/s, rad/s, A, A.
        """
        return initial_plant_state(self.p)

    def derivatives(self, t, x):
        """Equations (6)-(8) under the voltages ``inputs(t)``.

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            The state ``[x, y, theta, v1, v2, i1, i2]``.

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        u1, u2 = self.inputs(t)
        return plant_derivatives(self.constants, x, u1, u2, math)

    def rates(self, t, x, u, math=math):
        """Equations (6)-(8) under the voltages ``u`` (``derivatives`` with the inputs given).

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            The state ``[x, y, theta, v1, v2, i1, i2]``.
        u : list of float
            The voltages ``[u1, u2]``, in V.
        math : namespace, optional
            The ``math`` module, or ``DUAL_MATH`` on duals.

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        return plant_derivatives(self.constants, x, u[0], u[1], math)

    def outputs(self, x, u=None, math=math):
        """The outputs at state ``x``, the heading rate from (1).

        Parameters
        ----------
        x : list of float
            The state ``[x, y, theta, v1, v2, i1, i2]``.
        u : list of float or None, optional
            The voltages (the outputs do not depend on them).
        math : namespace, optional
            The ``math`` module, or ``DUAL_MATH`` on duals.

        Returns
        -------
        list of float
            ``[x, y, theta, theta_dot, omega1, omega2, i1, i2]`` in m, m, rad, rad/s, rad/s, rad/s, A, A.
        """
        x_, y, theta, v1, v2, i1, i2 = x
        return [x_, y, theta, theta_dot(self.constants, v1, v2), v1, v2, i1, i2]


class ReferenceRobotModel:
    """No inputs. Outputs: reference pose, vr, wr and vr_dot at the current time (docs/model.md §2)."""

    description = "Reference robot of the tracking problem (equation 9): constant or figure-eight profile"
    PARAMETERS = REFERENCE_PARAMETERS
    OUTPUTS = REFERENCE_OUTPUTS
    STATES = REFERENCE_STATES

    def initial_state(self):
        """The reference's state at the start.

        Returns
        -------
        list of float
            ``[xr, yr, thetar]`` in m, m, rad.
        """
        return initial_reference_state(self.p)

    def derivatives(self, t, x):
        """Equation (9) with the velocity profile of the parameters.

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            The state ``[xr, yr, thetar]``.

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        return reference_derivatives(self.p, t, x, math)

    def rates(self, t, x, u, math=math):
        """Equation (9) with the velocity profile of the parameters (``derivatives`` with the inputs given).

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            The state ``[xr, yr, thetar]``.
        u : list
            The inputs (none).
        math : namespace, optional
            The ``math`` module, or ``DUAL_MATH`` on duals.

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        return reference_derivatives(self.p, t, x, math)

    def outputs(self, x, u=None, math=math):
        """The outputs at state ``x`` and the current time.

        Parameters
        ----------
        x : list of float
            The state ``[xr, yr, thetar]``.
        u : list or None, optional
            The inputs (none).
        math : namespace, optional
            The ``math`` module, or ``DUAL_MATH`` on duals.

        Returns
        -------
        list of float
            ``[x_r, y_r, theta_r, v_r, omega_r, v_r_dot]`` in m, m, rad, m/s, rad/s, m/s2.
        """
        return [*x, *velocity(self.p, self.time)]


class DSCControllerModel:
    """Inputs: measurements and reference. Outputs: voltages u1, u2 (direct feedthrough) and internals.

    The measured inputs are held over a step; the 20 controller states are integrated with RK4
    (``discretization`` = 0) or one explicit Euler step per communication step (1). Until the first
    step the filter states are x2f = x2bar, x3f = x3bar of the current inputs, whatever the order of
    sets and reads; the first step starts from those of the inputs it holds (docs/model.md §5: the first
    measurements the controller sees). The beta guard
    (docs/model.md §5) is counted (``beta_guard_count``), shown (``beta_guard_active``) and logged.

    With ``start_on`` = valid_inputs, a controller that has not started and whose only refused
    values are inputs waits instead of discarding its steps: u = 0, S11 = S12 = S13 = 0, beta = 1,
    estimates at their initial values, ``started`` False. It starts (filters from the inputs then
    present) at the first step at which every input is valid. Both ends of the wait
    are logged as warnings; once started, a refused input discards steps as always.
    """

    description = "Adaptive dynamic surface controller for the electrically driven mobile robot (Section III)"
    PARAMETERS = CONTROLLER_PARAMETERS
    INPUTS = CONTROLLER_INPUTS
    OUTPUTS = CONTROLLER_OUTPUTS
    STATES = CONTROLLER_STATES
    LOCALS = FILTER_STATES
    INDICATORS = EVENT_INDICATORS
    FMU_STATE = {**SlaveCore.FMU_STATE, "beta_guard_count": int, "_guarded_last_step": bool, "waited_steps": int,
                 "held": _switches}

    def _init_core(self):
        self.held = None  # model exchange: the switches held since the last event; None: chosen at each evaluation
        self.beta_guard_count = 0
        self.waited_steps = 0
        self._guarded_last_step = False
        self._guard_seen = None
        super()._init_core()
        self.register_discrete_output(
            "beta_guard_count", "Number of steps in which beta fell below beta_min and the guard acted (docs/model.md §5)",
            lambda: self.beta_guard_count, boolean=False,
        )
        self.register_discrete_output(
            "beta_guard_active", "True while beta < beta_min at the current inputs and state",
            lambda: not self.waiting() and self.law().guarded, boolean=True,
        )
        self.register_discrete_output(
            "started", "True once the filter states have started (docs/model.md §5); False while initialising and while "
            "the controller waits for valid inputs (start_on = valid_inputs)",
            self.started, boolean=True,
        )

    def derive(self, p):
        """The design parameters of Section III from the parameters ``p``.

        Parameters
        ----------
        p : dict
            The parameter values by name.

        Returns
        -------
        Gains
            ``models.controller.gains(p)``.
        """
        return gains(p)

    def law(self):
        """The law (10)-(27) at the current state and the inputs set.

        Returns
        -------
        ControlLaw
            The voltages, the state derivative and the law's intermediate values.
        """
        return control_law(self.constants, self.current_state(), self.u, self.held)

    def started(self):
        """Whether the filter states have started (at the first step with every input valid).

        Returns
        -------
        bool
            True once started.
        """
        return self.state is not None

    def may_wait(self):
        """Whether refused inputs would make the controller wait: start_on = valid_inputs, not started.

        Returns
        -------
        bool
            True if they would.
        """
        return self.state is None and self.p["start_on"] == VALID_INPUTS

    def waiting(self):
        """Whether the controller waits for valid inputs (see the class).

        Returns
        -------
        bool
            True while it may wait and the only refused values are inputs.
        """
        return self.may_wait() and bool(self.rejected) and _INPUT_NAMES.issuperset(self.rejected)

    def report_refusal(self, kind, message):
        """Log the refusal of a value, unless it is an input the controller may wait for.

        Parameters
        ----------
        kind : {"parameter", "input"}
            What was refused.
        message : str
            Why, naming the variable, the value and the allowed range.
        """
        if kind == "input" and self.may_wait():
            return  # reported by the step that waits
        super().report_refusal(kind, message)

    def current_state(self):
        """The state: the initial estimates while waiting, else as ``SlaveCore.current_state``.

        Returns
        -------
        list of float
            The controller state ``xc`` (20 entries).
        """
        if self.waiting():
            return initial_controller_state(self.p)
        return super().current_state()

    def initial_state(self):
        """The state at the start: the initial estimates, the filters from the inputs (docs/model.md §5.2).

        Returns
        -------
        list of float
            The controller state ``xc`` (20 entries).
        """
        return start_filters(self.constants, initial_controller_state(self.p), self.u)

    def state_at(self, u, math=math):
        """The state as a function of the inputs ``u``: before the start the filters follow them (§5.2).

        Parameters
        ----------
        u : list of float
            The inputs (14 entries), duals for directional derivatives.
        math : namespace, optional
            The ``math`` module, or ``DUAL_MATH`` on duals.

        Returns
        -------
        list of float
            ``xc``: the state once started or while waiting, else the filters started from ``u``.
        """
        if self.state is not None or self.waiting():
            return self.current_state()
        return start_filters(self.constants, initial_controller_state(self.p), u, math)

    def rates(self, t, x, u, math=math):
        """The derivative of ``xc`` by the law (10)-(27) at the inputs ``u``, the switches held or chosen there.

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            The controller state ``xc`` (20 entries).
        u : list of float
            The inputs (14 entries).
        math : namespace, optional
            The ``math`` module, or ``DUAL_MATH`` on duals.

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        return control_law(self.constants, x, u, self.held, math).derivative

    def derivatives(self, t, x):
        """The derivative of ``xc`` by the law (10)-(27) at the inputs ``inputs(t)``; notes a guard that acts.

        Parameters
        ----------
        t : float
            Time, in s.
        x : list of float
            The controller state ``xc`` (20 entries).

        Returns
        -------
        list of float
            The time derivative of each entry of ``x``.
        """
        law = control_law(self.constants, x, self.inputs(t), self.held, math)
        if law.guarded and self._guard_seen is None:
            self._guard_seen = (t, law.beta)
        return law.derivative

    def substep_count(self, step_size):
        """How many sub-steps ``integrate`` takes: 1 with ``discretization`` = euler.

        Parameters
        ----------
        step_size : float
            The communication step, in s.

        Returns
        -------
        int
            1 (euler) or the RK4 sub-steps no longer than ``max_step``.
        """
        return 1 if self.p["discretization"] == EULER else super().substep_count(step_size)

    def integrate(self, t, x, step_size):
        """The state after ``step_size``: RK4 or one explicit Euler step, as ``discretization`` says.

        Parameters
        ----------
        t : float
            The start time, in s.
        x : list of float
            The controller state at ``t``.
        step_size : float
            The communication step, in s.

        Returns
        -------
        list of float
            The controller state at ``t + step_size``.
        """
        if self.p["discretization"] == EULER:
            return euler_step(self.derivatives, t, x, step_size)
        return super().integrate(t, x, step_size)

    def do_step(self, current_time, step_size):
        """Take the communication step, or wait for valid inputs; count and log the beta guard.

        Parameters
        ----------
        current_time : float
            The communication point the step starts from, in s.
        step_size : float
            The communication step, in s.

        Returns
        -------
        bool
            True if taken (or waited), False if discarded (see ``SlaveCore.do_step``).
        """
        if self.waiting():
            self._wait(current_time, step_size)
            return True
        if self.state is None and self.waited_steps and not self.rejected:
            self.log(
                f"{self.instance_name}: every input valid at t = {current_time:.6g} s: the controller starts "
                f"after waiting {self.waited_steps} step(s) with u = 0 (start_on = valid_inputs)",
                self.library.status.warning,
            )
        self._guard_seen = None
        ok = super().do_step(current_time, step_size)
        self._count_guard()
        return ok

    def _wait(self, current_time, step_size):
        """A step waited for valid inputs; the first is logged."""
        if not self.waited_steps:
            self.log(
                f"{self.instance_name}: waits for valid inputs from t = {current_time:.6g} s with u = 0 "
                f"(start_on = valid_inputs): {'; '.join(self.rejected.values())}",
                self.library.status.warning,
            )
        self.waited_steps += 1
        self._stepped(current_time + step_size)

    def _count_guard(self):
        """Count a step in which the guard acted; log the first of a run of such steps."""
        if self._guard_seen is not None:
            self.beta_guard_count += 1
            if not self._guarded_last_step:
                t, beta = self._guard_seen
                self.log(
                    f"{self.instance_name}: beta = {beta:.6g} < beta_min = {self.p['beta_min']:g} at t = {t:.6g} s: "
                    "h2 divides by beta_min (outside the region of Remark 3)", self.library.status.warning,
                )
        self._guarded_last_step = self._guard_seen is not None

    def outputs(self, x, u=None, math=math):
        """The outputs at state ``x`` and inputs ``u``: u = 0 and the surfaces zero while waiting.

        Parameters
        ----------
        x : list of float
            The controller state ``xc`` (20 entries).
        u : list of float or None, optional
            The inputs (14 entries). Default None: those set.
        math : namespace, optional
            The ``math`` module, or ``DUAL_MATH`` on duals.

        Returns
        -------
        list of float
            The outputs in the order of ``CONTROLLER_OUTPUTS``: voltages (26), surfaces (10), (12),
            beta (13), estimates and their norms.
        """
        W1_hat, W2_hat = x[W1_SLICE], x[W2_SLICE]
        estimates = [x[0], x[1], weight_norm(W1_hat, math), weight_norm(W2_hat, math), *W1_hat, *W2_hat]
        if self.waiting():
            return [*_WAITING_LAW_OUTPUTS, *estimates]
        law = control_law(self.constants, x, self.u if u is None else u, self.held, math)
        return [law.u1, law.u2, law.S11, law.S12, law.S13, law.beta, *estimates]

    def indicator_values(self, x):
        """The event indicators of the wrap and the guard at the inputs set (docs/model.md §5.13).

        Parameters
        ----------
        x : list of float
            The controller state (the indicators depend on the inputs only).

        Returns
        -------
        list of float
            ``[cos((thetar - theta) / 2), beta - beta_min]``.
        """
        return event_indicators(self.constants, self.u)

    def update_discrete_states(self):
        """Model exchange, event mode: hold the switches of the current inputs until the next event.

        An engaging guard is counted and logged as in co-simulation.
        """
        held = switches(self.constants, self.u)
        if held.guarded and not (self.held and self.held.guarded):
            self.beta_guard_count += 1
            self.log(
                f"{self.instance_name}: beta < beta_min = {self.p['beta_min']:g} from t = {self.time:.6g} s: h2 "
                "divides by beta_min (outside the region of Remark 3)", self.library.status.warning,
            )
        self.held = held
        super().update_discrete_states()
