"""The FMUs' variables with the paper's values (Section IV): the one source of truth for defaults."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

__all__ = [
    "PLANT_PARAMETERS",
    "PLANT_INPUTS",
    "PLANT_OUTPUTS",
    "REFERENCE_PARAMETERS",
    "REFERENCE_OUTPUTS",
    "CONTROLLER_PARAMETERS",
    "CONTROLLER_INPUTS",
    "CONTROLLER_OUTPUTS",
    "DRIVE_OUTPUTS",
    "PROFILES",
    "DISCRETIZATIONS",
    "ADAPTATIONS",
    "VOLTAGE_LIMITS",
    "START_ON",
    "INPUT_COUPLINGS",
    "TRACED",
    "DEFAULT_TOLERANCE",
]

POSITIVE = "positive"
NONNEGATIVE = "nonnegative"
ANY = "any"


@dataclass(frozen=True)
class Variable:
    """One FMU variable (docs/model.md): name, start value in ``unit`` (the paper's value for parameters, Section IV),
    SI unit (``"1"`` for none) as the model description writes it, description (citing the paper's equation where
    it has one), and allowed range: ``bound`` finite, > 0 or >= 0, and inclusive ``minimum``, ``maximum`` beyond it.
    ``tunable``: a parameter that may change between communication points; ``integer``: an Integer (else Real);
    ``choices``: the names of an Integer's values 0, 1, ... (a scenario gives the name, the FMU takes the number).
    """

    name: str
    start: float
    unit: str
    description: str
    bound: str = ANY
    tunable: bool = False
    integer: bool = False
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple = ()

    def check(self, value: float) -> str | None:
        """Why ``value`` (in the variable's unit) is not allowed, naming the variable and the value; None if it is."""
        if not math.isfinite(value):
            return f"{self.name} = {value} is not finite"
        if self.bound == POSITIVE and not value > 0:
            return f"{self.name} = {value} is not allowed: it must be > 0"
        if self.bound == NONNEGATIVE and not value >= 0:
            return f"{self.name} = {value} is not allowed: it must be >= 0"
        if self.integer and value != int(value):
            return f"{self.name} = {value} is not allowed: it must be a whole number"
        if self.minimum is not None and value < self.minimum:
            return f"{self.name} = {value} is not allowed: it must be >= {self.minimum:g}"
        if self.maximum is not None and value > self.maximum:
            return f"{self.name} = {value} is not allowed: it must be <= {self.maximum:g}"
        return None

    @property
    def allowed(self) -> str:
        """The allowed range in words, for error messages."""
        text = {POSITIVE: "> 0", NONNEGATIVE: ">= 0", ANY: "finite"}[self.bound]
        if self.minimum is not None:
            text += f" and >= {self.minimum:g}"
        if self.maximum is not None:
            text += f" and <= {self.maximum:g}"
        return text + (", whole number" if self.integer else "")


def defaults(variables) -> dict:
    """``{name: start}`` of ``variables``, in their order."""
    return {v.name: v.start for v in variables}


def _per_wheel(name, value, unit, what, bound=POSITIVE):
    return tuple(
        Variable(f"{name}{i}", value, unit, f"{what}, {side} wheel (docs/model.md §1, eq. 5)", bound)
        for i, side in ((1, "right"), (2, "left"))
    )


# How inputs vary over a communication step (the ``coupling`` parameter): 0 = hold, 1 = extrapolate
# (linearly from the inputs of the previous communication point to those set for this step's start),
# 2 = interpolate (the inputs set are those of the step's end, the previous ones those of its start).
INPUT_COUPLINGS = ("hold", "extrapolate", "interpolate")

DEFAULT_TOLERANCE = 1e-6
"""The relative tolerance of model exchange where none is given: the project's model-exchange runs measure
at it (each state's absolute tolerance is this times its nominal), and every FMU's DefaultExperiment
declares it."""

MAX_STEP = Variable(
    "max_step", 1e-3, "s",
    "Longest internal RK4 sub-step between communication points (1 us to 1 s: it bounds the work of a step)",
    POSITIVE, tunable=True, minimum=1e-6, maximum=1.0,
)

# Whether a step and the model's evaluations run in the C traced from the model (the ``traced`` parameter,
# docs/traced-c.md).
TRACED = ("on", "off")

TRACED_PARAMETER = Variable(
    "traced", 0, "1",
    "Where the model's equations run (docs/traced-c.md): 0 = on (in the C traced from the Python model at build "
    "time, bit for bit the same results), 1 = off (in Python)",
    NONNEGATIVE, integer=True, tunable=True, maximum=len(TRACED) - 1, choices=TRACED,
)

# Whether the motor drivers limit the applied voltage (the ``voltage_limit`` parameter, docs/model.md §5.14).
VOLTAGE_LIMITS = ("off", "on")


def _load(name, unit, what, bound=ANY):
    return tuple(
        Variable(f"{name}{i}", 0.0, unit, f"{what} of the disturbance torque on the {side} wheel, tau_d{i}(t) = "
                 f"tau_dc{i} + tau_da{i} sin(2 pi f_d{i} t + phi_d{i}): a load in (2), none while tau_dc{i} and "
                 f"tau_da{i} are 0 (docs/model.md §5.14)", bound)
        for i, side in ((1, "right"), (2, "left"))
    )


PLANT_PARAMETERS = (
    Variable("R", 0.75, "m", "Half the distance between the driving wheels", POSITIVE),
    Variable("d", 0.3, "m", "Distance from the wheel axle midpoint to the centre of mass", NONNEGATIVE),
    Variable("r", 0.15, "m", "Wheel radius", POSITIVE),
    Variable("mc", 30.0, "kg", "Mass of the platform without wheels and motors", POSITIVE),
    Variable("mw", 1.0, "kg", "Mass of each wheel with its motor", POSITIVE),
    Variable("Ic", 15.625, "kg.m2", "Platform moment of inertia about the vertical axis through the centre of mass", POSITIVE),
    Variable("Iw", 0.005, "kg.m2", "Wheel with motor moment of inertia about the wheel axis", POSITIVE),
    Variable("Im", 0.0025, "kg.m2", "Wheel with motor moment of inertia about a wheel diameter", NONNEGATIVE),
    Variable("d11", 5.0, "N.m.s/rad", "Viscous damping, right wheel (matrix D)", NONNEGATIVE),
    Variable("d22", 5.0, "N.m.s/rad", "Viscous damping, left wheel (matrix D)", NONNEGATIVE),
    *_per_wheel("Ra", 1.6, "Ohm", "Armature resistance"),
    *_per_wheel("La", 0.048, "H", "Armature inductance"),
    *_per_wheel("KE", 0.19, "V.s/rad", "Back-EMF constant"),
    *_per_wheel("KT", 0.2613, "N.m/A", "Torque constant"),
    *_per_wheel("N", 62.55, "1", "Gear ratio"),
    Variable("x0", 2.5, "m", "Initial x position of the robot"),
    Variable("y0", 1.0, "m", "Initial y position of the robot"),
    Variable("theta0", 1.5707963267948966, "rad", "Initial heading of the robot"),
    Variable("omega1_0", 0.0, "rad/s", "Initial angular velocity, right wheel (docs/model.md §5: at rest)"),
    Variable("omega2_0", 0.0, "rad/s", "Initial angular velocity, left wheel (docs/model.md §5: at rest)"),
    Variable("i1_0", 0.0, "A", "Initial motor current, right wheel"),
    Variable("i2_0", 0.0, "A", "Initial motor current, left wheel"),
    Variable(
        "coupling", 0, "1",
        "How u1, u2 vary over a communication step (docs/model.md §5.10): 0 = hold (constant: zero-order "
        "hold), 1 = extrapolate (linearly from the values of the previous communication point through "
        "those of this one; the first step holds)",
        NONNEGATIVE, integer=True, maximum=1, choices=INPUT_COUPLINGS[:2],
    ),
    Variable(
        "voltage_limit", 0, "1",
        "Motor drivers (docs/model.md §1, §5.14): 0 = off (each motor gets its input u_j), 1 = on (it gets "
        "clip(u_j, -u_max_j, u_max_j): the driver saturates)",
        NONNEGATIVE, integer=True, maximum=len(VOLTAGE_LIMITS) - 1, choices=VOLTAGE_LIMITS,
    ),
    *(Variable(f"u_max{i}", 200.0, "V", f"Largest voltage magnitude the {side} wheel's driver applies, with "
               "voltage_limit = on (docs/model.md §5.14)", POSITIVE) for i, side in ((1, "right"), (2, "left"))),
    *_load("tau_dc", "N.m", "Constant part"),
    *_load("tau_da", "N.m", "Amplitude of the sinusoid", NONNEGATIVE),
    *_load("f_d", "Hz", "Frequency of the sinusoid", NONNEGATIVE),
    *_load("phi_d", "rad", "Phase at t = 0 of the sinusoid"),
    MAX_STEP,
    TRACED_PARAMETER,
)

PLANT_INPUTS = (
    Variable("u1", 0.0, "V", "Motor voltage, right wheel"),
    Variable("u2", 0.0, "V", "Motor voltage, left wheel"),
)

PLANT_OUTPUTS = (
    Variable("x", 0.0, "m", "Position x of the axle midpoint (eq. 1)"),
    Variable("y", 0.0, "m", "Position y of the axle midpoint (eq. 1)"),
    Variable("theta", 0.0, "rad", "Heading, continuous (not wrapped)"),
    Variable("theta_dot", 0.0, "rad/s", "Heading rate, as a gyro measures it (eq. 1)"),
    Variable("omega1", 0.0, "rad/s", "Angular velocity, right wheel (z1)"),
    Variable("omega2", 0.0, "rad/s", "Angular velocity, left wheel (z2)"),
    Variable("i1", 0.0, "A", "Motor current, right wheel"),
    Variable("i2", 0.0, "A", "Motor current, left wheel"),
)

DRIVE_OUTPUTS = (
    Variable("u1_applied", 0.0, "V", "Voltage the driver applies to the right motor: clip(u1, -u_max1, u_max1) with "
             "voltage_limit = on, else u1 (docs/model.md §5.14)"),
    Variable("u2_applied", 0.0, "V", "Voltage the driver applies to the left motor: clip(u2, -u_max2, u_max2) with "
             "voltage_limit = on, else u2 (docs/model.md §5.14)"),
    Variable("saturation_time", 0.0, "s", "Time during which either motor's voltage was limited (docs/model.md "
             "§5.14)"),
)
"""The MobileRobot FMU's outputs after ``PLANT_OUTPUTS``: what its motor drivers do (the controller measures none)."""

PROFILES = ("constant", "figure_eight")
DISCRETIZATIONS = ("rk4", "euler")
ADAPTATIONS = ("sigma", "e", "projection", "none")
START_ON = ("first_use", "valid_inputs")

REFERENCE_PARAMETERS = (
    Variable("x0", 2.0, "m", "Initial x position of the reference robot"),
    Variable("y0", 2.0, "m", "Initial y position of the reference robot"),
    Variable("theta0", 0.0, "rad", "Initial heading of the reference robot"),
    Variable(
        "profile", 0, "1", "Velocity profile: 0 = constant (v_r = vr0, omega_r = wr0), "
        "1 = figure eight (speed and turn rate of x = A sin(2 pi t/T), y = B sin(4 pi t/T))",
        NONNEGATIVE, integer=True, maximum=len(PROFILES) - 1, choices=PROFILES,
    ),
    Variable("vr0", 1.0, "m/s", "Linear velocity of the constant profile (Assumption 2: > 0)", POSITIVE),
    Variable("wr0", 0.2, "rad/s", "Angular velocity of the constant profile"),
    Variable("eight_A", 3.0, "m", "Figure eight: half width A", POSITIVE),
    Variable("eight_B", 1.5, "m", "Figure eight: half height of each lobe B", POSITIVE),
    Variable("eight_T", 30.0, "s", "Figure eight: period T of one full figure", POSITIVE),
    MAX_STEP,
    TRACED_PARAMETER,
)

REFERENCE_OUTPUTS = (
    Variable("x_r", 0.0, "m", "Reference position x (eq. 9)"),
    Variable("y_r", 0.0, "m", "Reference position y (eq. 9)"),
    Variable("theta_r", 0.0, "rad", "Reference heading, continuous (eq. 9)"),
    Variable("v_r", 0.0, "m/s", "Reference linear velocity vr"),
    Variable("omega_r", 0.0, "rad/s", "Reference angular velocity wr"),
    Variable("v_r_dot", 0.0, "m/s2", "Time derivative of vr"),
)


def _gains(name, values, what, unit="1"):
    return tuple(
        Variable(f"{name}_{i}", v, unit, f"{what}, diagonal entry {i}", POSITIVE, tunable=True)
        for i, v in enumerate(values, start=1)
    )


CONTROLLER_PARAMETERS = (
    Variable("k1", 2.0, "1", "Gain k1 of the S13 transformation (eq. 12)", POSITIVE, tunable=True),
    Variable("k2", 2.0, "1", "Gain k2 of the virtual control h1 (eq. 14)", POSITIVE, tunable=True),
    Variable("k3", 1.0, "1", "Gain k3 of the virtual control h2 (eq. 14)", POSITIVE, tunable=True),
    Variable("k4", 1.0, "1", "Gain k4 of the virtual current x3bar (eq. 20)", POSITIVE, tunable=True),
    Variable("k5", 1.0, "1", "Gain k5 of the voltage law u (eq. 26)", POSITIVE, tunable=True),
    Variable("gamma1", 2.0, "1", "Adaptation gain of a1_hat (eq. 15)", POSITIVE, tunable=True),
    Variable("gamma2", 2.0, "1", "Adaptation gain of a2_hat (eq. 16)", POSITIVE, tunable=True),
    Variable("sigma1", 0.001, "1", "Sigma-modification of a1_hat (eq. 15); the gain of e-modification "
             "(adaptation = e)", POSITIVE, tunable=True),
    Variable("sigma2", 0.001, "1", "Sigma-modification of a2_hat (eq. 16); the gain of e-modification "
             "(adaptation = e)", POSITIVE, tunable=True),
    Variable("sigma3", 0.001, "1", "Sigma-modification of W1_hat (eq. 21); the gain of e-modification "
             "(adaptation = e)", POSITIVE, tunable=True),
    Variable("sigma4", 0.001, "1", "Sigma-modification of W2_hat (eq. 27); the gain of e-modification "
             "(adaptation = e)", POSITIVE, tunable=True),
    Variable("tau2", 0.01, "s", "Time constant of the first-order filter of x2bar (eq. 17)", POSITIVE, tunable=True),
    Variable("tau3", 0.01, "s", "Time constant of the first-order filter of x3bar (eq. 23)", POSITIVE, tunable=True),
    *_gains("Gamma1", (1e-4,) * 8, "Adaptation gain matrix Gamma1 of W1_hat (eq. 21)"),
    *_gains("Gamma2", (0.2, 0.2, 0.2, 0.2, 1e-5, 1e-5), "Adaptation gain matrix Gamma2 of W2_hat (eq. 27)"),
    Variable("a1_hat0", 0.0, "1/m", "Initial estimate a1_hat(0) (docs/model.md §5: zero)"),
    Variable("a2_hat0", 0.0, "1", "Initial estimate a2_hat(0) (docs/model.md §5: zero)"),
    *(Variable(f"W1_hat0_{i}", 0.0, "1", f"Initial estimate W1_hat(0), entry {i}") for i in range(1, 9)),
    *(Variable(f"W2_hat0_{i}", 0.0, "1", f"Initial estimate W2_hat(0), entry {i}") for i in range(1, 7)),
    Variable(
        "discretization", 0, "1",
        "Integration of the controller states over a communication step: 0 = rk4 (RK4 in sub-steps of "
        "at most max_step: the continuous law), 1 = euler (one explicit Euler step per communication "
        "step: an embedded controller sampled at the communication step)",
        NONNEGATIVE, integer=True, maximum=len(DISCRETIZATIONS) - 1, choices=DISCRETIZATIONS,
    ),
    Variable(
        "start_on", 0, "1",
        "When the controller starts its filter states (docs/model.md §5): 0 = first_use (at the first step, from the "
        "inputs it holds; an input out of range is refused and every step discarded), "
        "1 = valid_inputs (while only inputs are refused and it has not started, it waits: u = 0, states "
        "unchanged, steps accepted; it starts at the first step with every input valid; for masters "
        "that start their connections at 0 without an initial exchange, such as fmpy.ssp.simulate_ssp)",
        NONNEGATIVE, integer=True, maximum=len(START_ON) - 1, choices=START_ON,
    ),
    Variable(
        "coupling", 0, "1",
        "How the inputs vary over a communication step (docs/model.md §5.10): 0 = hold (constant), "
        "1 = extrapolate (the inputs set before a step are those of its start, as a Jacobi master sets "
        "them: extrapolated linearly from those of the previous communication point), 2 = interpolate "
        "(they are those of its end, as a Gauss-Seidel master sets them: interpolated linearly from those "
        "of the previous step); the first step holds",
        NONNEGATIVE, integer=True, maximum=len(INPUT_COUPLINGS) - 1, choices=INPUT_COUPLINGS,
    ),
    Variable(
        "beta_min", 0.05, "1",
        "Guard of beta (docs/model.md §5): where beta < beta_min, h2 divides by beta_min instead", POSITIVE, tunable=True,
    ),
    Variable(
        "adaptation", 0, "1",
        "Adaptation law of a1_hat, a2_hat, W1_hat, W2_hat (eqs. 15, 16, 21, 27; Remark 4; docs/model.md §3): "
        "0 = sigma (sigma-modification: the paper's), 1 = e (e-modification: the leakage sigma_i scaled by the "
        "norm of the law's error surface), 2 = projection (no leakage; each estimate kept in its set: "
        "a1_min..a1_max, a2_min..a2_max, |W1_hat| <= W1_max, |W2_hat| <= W2_max), 3 = none (no leakage)",
        NONNEGATIVE, integer=True, maximum=len(ADAPTATIONS) - 1, choices=ADAPTATIONS,
    ),
    Variable("a1_min", 0.0, "1/m", "Projection: lower bound of a1_hat (adaptation = projection; a1 = 1/r)"),
    Variable("a1_max", 20.0, "1/m", "Projection: upper bound of a1_hat (adaptation = projection; a1 = 1/r)"),
    Variable("a2_min", 0.0, "1", "Projection: lower bound of a2_hat (adaptation = projection; a2 = R/r)"),
    Variable("a2_max", 20.0, "1", "Projection: upper bound of a2_hat (adaptation = projection; a2 = R/r)"),
    Variable("W1_max", 1.0, "1", "Projection: bound of the Euclidean norm of W1_hat (adaptation = projection)",
             POSITIVE),
    Variable("W2_max", 40.0, "1", "Projection: bound of the Euclidean norm of W2_hat (adaptation = projection)",
             POSITIVE),
    MAX_STEP,
    TRACED_PARAMETER,
)

# The controller's input start values: the default scenario's initial state (the robot at rest at
# its initial pose, the reference at its initial pose with its constant velocities).
_PLANT_START = defaults(PLANT_PARAMETERS)
_REFERENCE_START = defaults(REFERENCE_PARAMETERS)
_INITIAL_MEASUREMENTS = {
    "x": _PLANT_START["x0"], "y": _PLANT_START["y0"], "theta": _PLANT_START["theta0"],
    "omega1": _PLANT_START["omega1_0"], "omega2": _PLANT_START["omega2_0"],
    "i1": _PLANT_START["i1_0"], "i2": _PLANT_START["i2_0"],
    "x_r": _REFERENCE_START["x0"], "y_r": _REFERENCE_START["y0"], "theta_r": _REFERENCE_START["theta0"],
    "v_r": _REFERENCE_START["vr0"], "omega_r": _REFERENCE_START["wr0"],
}

CONTROLLER_INPUTS = (
    *(replace(v, start=_INITIAL_MEASUREMENTS.get(v.name, 0.0),
              description=f"Measured: {v.description[0].lower()}{v.description[1:]}") for v in PLANT_OUTPUTS),
    *(replace(v, start=_INITIAL_MEASUREMENTS[v.name], bound=POSITIVE, description=f"{v.description} (Assumption 2: > 0)")
      if v.name == "v_r" else replace(v, start=_INITIAL_MEASUREMENTS.get(v.name, 0.0)) for v in REFERENCE_OUTPUTS),
)

CONTROLLER_OUTPUTS = (
    Variable("u1", 0.0, "V", "Motor voltage, right wheel (eq. 26)"),
    Variable("u2", 0.0, "V", "Motor voltage, left wheel (eq. 26)"),
    Variable("S11", 0.0, "m", "Longitudinal tracking error in the robot frame (eq. 10)"),
    Variable("S12", 0.0, "m", "Lateral tracking error in the robot frame (eq. 10)"),
    Variable("S13", 0.0, "rad", "Transformed heading error (eq. 12)"),
    Variable("beta", 1.0, "1", "beta = 1 + k1 vr S11 / (1 + (k1 S12 vr)^2), before the guard (eq. 14)"),
    Variable("a1_hat", 0.0, "1/m", "Estimate of a1 = 1/r (eq. 15)"),
    Variable("a2_hat", 0.0, "1", "Estimate of a2 = R/r (eq. 16)"),
    Variable("W1_hat_norm", 0.0, "1", "Euclidean norm of W1_hat (eq. 21)"),
    Variable("W2_hat_norm", 0.0, "1", "Euclidean norm of W2_hat (eq. 27)"),
    *(Variable(f"W1_hat_{i}", 0.0, "1", f"Estimate of W1 entry {i} (eq. 21)") for i in range(1, 9)),
    *(Variable(f"W2_hat_{i}", 0.0, "1", f"Estimate of W2 entry {i} (eq. 27)") for i in range(1, 7)),
)

