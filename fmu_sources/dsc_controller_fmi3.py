"""DSCController.fmu, FMI 3.0: the adaptive DSC of SPEC 3 (equations 10-27), as ``dsc_controller.py`` for FMI 2.0."""

from pythonfmu3 import Boolean, Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Variability, Int32

from dsc_fmu.fmi3_slave import DscSlave
from dsc_fmu.models.controller import (
    W1_SLICE, W2_SLICE, control_law, gains, initial_controller_state, start_filters,
)
from dsc_fmu.models.parameters import CONTROLLER_INPUTS, CONTROLLER_OUTPUTS, CONTROLLER_PARAMETERS, DISCRETIZATIONS
from dsc_fmu.models.rk4 import euler_step

EULER = DISCRETIZATIONS.index("euler")


def _norm(values):
    return sum(v * v for v in values) ** 0.5


class DSCController(DscSlave, Fmi3Slave):
    """Inputs: measurements and reference. Outputs: voltages u1, u2 (direct feedthrough) and internals.

    The measured inputs are held over a step; the 20 controller states are integrated with RK4
    (``discretization`` = 0) or one explicit Euler step per communication step (1).
    The filter states start at x2f = x2bar, x3f = x3bar of the inputs present at the first output
    read or step after initialisation (SPEC 5: the first measurements the controller sees).
    """

    description = "Adaptive dynamic surface controller for the electrically driven mobile robot (Section III)"
    PARAMETERS = CONTROLLER_PARAMETERS
    INPUTS = CONTROLLER_INPUTS
    OUTPUTS = CONTROLLER_OUTPUTS

    def __init__(self, **kwargs):
        self.beta_guard_count = 0
        self._guarded_last_step = False
        self._guard_seen = None
        super().__init__(**kwargs)
        self.register_variable(Int32(
            "beta_guard_count", causality=Fmi3Causality.output, variability=Fmi3Variability.discrete,
            initial=Fmi3Initial.calculated,
            description="Number of steps in which beta fell below beta_min and the guard acted (SPEC 5)",
            getter=lambda: self.beta_guard_count, setter=lambda value: None,
        ))
        self.register_variable(Boolean(
            "beta_guard_active", causality=Fmi3Causality.output, variability=Fmi3Variability.discrete,
            initial=Fmi3Initial.calculated,
            description="True while beta < beta_min at the current inputs and state",
            getter=lambda: self.law().guarded, setter=lambda value: None,
        ))

    def derive(self, p):
        return gains(p)

    def law(self):
        return control_law(self.constants, self.current_state(), self.u)

    def initial_state(self):
        return start_filters(self.constants, initial_controller_state(self.p), self.u)

    def derivatives(self, t, x):
        law = control_law(self.constants, x, self.u)
        if law.guarded and self._guard_seen is None:
            self._guard_seen = (t, law.beta)
        return law.derivative

    def integrate(self, t, x, step_size):
        if self.p["discretization"] == EULER:
            return euler_step(self.derivatives, t, x, step_size)
        return super().integrate(t, x, step_size)

    def do_step(self, current_time, step_size):
        self._guard_seen = None
        ok = super().do_step(current_time, step_size)
        if self._guard_seen is not None:
            self.beta_guard_count += 1
            if not self._guarded_last_step:
                t, beta = self._guard_seen
                self.log_warning(
                    f"{self.instance_name}: beta = {beta:.6g} < beta_min = {self.p['beta_min']:g} at t = {t:.6g} s: "
                    "h2 divides by beta_min (outside the region of Remark 3)"
                )
        self._guarded_last_step = self._guard_seen is not None
        return ok

    def outputs(self, x):
        law = control_law(self.constants, x, self.u)
        W1_hat, W2_hat = x[W1_SLICE], x[W2_SLICE]
        return [
            law.u1, law.u2, law.S11, law.S12, law.S13, law.beta, x[0], x[1],
            _norm(W1_hat), _norm(W2_hat), *W1_hat, *W2_hat,
        ]

    def extra_state(self):
        return {"beta_guard_count": self.beta_guard_count, "guarded_last_step": self._guarded_last_step}

    def set_extra_state(self, extra):
        self.beta_guard_count = extra["beta_guard_count"]
        self._guarded_last_step = extra["guarded_last_step"]
