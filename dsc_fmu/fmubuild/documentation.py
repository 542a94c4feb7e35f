"""The ``documentation/index.html`` of each FMU, written at build time from its model description, and
what the importing machine needs (``documentation/externalDependencies.txt`` too)."""

from __future__ import annotations

from html import escape
from xml.etree import ElementTree as ET

from ..registry import CONTROLLER, PLANT, REFERENCE

__all__ = ["PAPER", "EQUATIONS", "REQUIREMENTS"]

PAPER = ('"Adaptive tracking control of nonholonomic mobile robots considering actuator dynamics", '
         "a dynamic surface control (DSC) design; equation numbers below are the paper's.")

# The equations each FMU implements (docs/model.md, sections 1-3), as preformatted text.
EQUATIONS = {
    PLANT: """\
States: pose q = [x, y, theta], wheel speeds z = [omega1, omega2], currents ia = [i1, i2].
Input: motor voltages u = [u1, u2]. Index 1 = right wheel, 2 = left wheel.

Kinematics (1):
  x_dot     = 0.5 r cos(theta) (omega1 + omega2)
  y_dot     = 0.5 r sin(theta) (omega1 + omega2)
  theta_dot = 0.5 r / R (omega1 - omega2)
Dynamics (2): M z_dot + C(q_dot) z + D z = tau
  m   = mc + 2 mw,   I = mc d^2 + 2 mw R^2 + Ic + 2 Im
  m11 = 0.25 r^2 / R^2 (m R^2 + I) + Iw,   m12 = 0.25 r^2 / R^2 (m R^2 - I)
  M   = [[m11, m12], [m12, m11]],  C = c [[0, theta_dot], [-theta_dot, 0]],  c = 0.5 r^2 mc d / R
  D   = diag(d11, d22)
DC motors through gears (5):
  tau = N KT ia,   La ia_dot = u - Ra ia - N KE z
Motor drivers and loads (not the paper's; off by default):
  voltage_limit = 1 (on): the motors get ua_j = clip(u_j, -u_max_j, u_max_j) instead of u_j
  (outputs u1_applied, u2_applied; saturation_count, saturation_time, saturation_active say how often
  and how long; in model exchange held between events at the roots of u_max_j -+ u_j)
  disturbance torque in (2): M z_dot + C z + D z = tau - tau_d,
  tau_dj(t) = tau_dcj + tau_daj sin(2 pi f_dj t + phi_dj)   (N.m, Hz, rad; positive: a load)
Integrated with classical RK4 in equal sub-steps of at most max_step per communication step.""",
    REFERENCE: """\
Reference robot (9):
  x_r_dot = v_r cos(theta_r),  y_r_dot = v_r sin(theta_r),  theta_r_dot = omega_r
Profiles:
  profile = 0 (constant):     v_r = vr0, omega_r = wr0, v_r_dot = 0
  profile = 1 (figure eight): speed, turn rate and acceleration along
                              x = A sin(W t), y = B sin(2 W t), W = 2 pi / T
v_r must stay > 0 (Assumption 2).
Integrated with classical RK4 in equal sub-steps of at most max_step per communication step.""",
    CONTROLLER: """\
Step 1 (kinematics), error surfaces (10), (12):
  S11 =  cos(theta)(x_r - x) + sin(theta)(y_r - y)
  S12 = -sin(theta)(x_r - x) + cos(theta)(y_r - y)
  a   = arctan(k1 S12 v_r),  S13 = wrap(theta_r - theta) + a,  den = 1 + (k1 S12 v_r)^2
  alpha1 = (k1 v_r^2 sin(S13 - a) + k1 S12 v_r_dot) / den
  alpha2 = (sin(S13 - a) + sin(a)) / S13          (cos(a) as S13 -> 0)
  beta   = 1 + k1 v_r S11 / den                   (divides by beta_min where beta < beta_min)
Virtual control (14):
  h1 = a1_hat v_r cos(S13 - a) + k2 S11 + 0.5 (k1 v_r)^4 S11^3
  h2 = (a1_hat alpha2 v_r S12 + a2_hat (omega_r + alpha1) + k3 S13 + 0.5 S13^3) / beta
  x2bar = [h1 + h2, h1 - h2]
Adaptation (15), (16):
  a1_hat_dot = gamma1 v_r (S11 cos(S13 - a) + alpha2 S12 S13) - sigma1 gamma1 a1_hat
  a2_hat_dot = gamma2 (omega_r + alpha1) S13 - sigma2 gamma2 a2_hat
Filter (17): tau2 x2f_dot + x2f = x2bar
Step 2 (robot dynamics), (18)-(22):
  S2 = z - x2f
  Phi1 = [[-theta_dot omega2, 0, -omega1, 0, -x2f_dot1, -x2f_dot2, 0, 0],
          [0, theta_dot omega1, 0, -omega2, 0, 0, -x2f_dot2, -x2f_dot1]]
  x3bar = -k4 S2 - Phi1 W1_hat,   W1_hat_dot = Gamma1 Phi1^T S2 - sigma3 Gamma1 W1_hat
Filter (23): tau3 x3f_dot + x3f = x3bar
Step 3 (actuators), (24)-(27):
  S3 = ia - x3f
  Phi2 = [[-i1, 0, -omega1, 0, -x3f_dot1, 0], [0, -i2, 0, -omega2, 0, -x3f_dot2]]
  u = -k5 S3 - Phi2 W2_hat,   W2_hat_dot = Gamma2 Phi2^T S3 - sigma4 Gamma2 W2_hat
Filters start at x2f = x2bar, x3f = x3bar of the first inputs; the 20 states are integrated with
RK4 in sub-steps of at most max_step (discretization = 0) or one Euler step (discretization = 1).
With start_on = 1 (valid_inputs) the controller waits with u = 0 until every input is valid (for
masters without an initial exchange) and starts from the first valid inputs; output started.""",
}

# What the importing machine needs (docs/other-tools.md, "What the importing machine needs"): the page's
# Requirements and the FMU's documentation/externalDependencies.txt.
REQUIREMENTS = (
    "The FMU needs no execution tool (needsExecutionTool = false): it carries the model and the Python code "
    "that runs it (standard library only), and its binary loads CPython as a library. The importing machine "
    "needs x86-64 or aarch64 Linux (glibc 2.17 or newer), x86-64 Windows or macOS (11.0 or newer on Apple "
    "Silicon, 10.13 or newer on Intel) and a 64-bit CPython 3.9 or newer, which the FMU finds by itself: a "
    "CPython already in the process, DSC_FMU_PYTHON naming a CPython's folder or shared library "
    "(libpython3.X.so.1.0 on Linux, libpython3.X.dylib or a framework's Python on macOS, python3X.dll on "
    "Windows), the Python that built the FMU, then the system's (on Linux the dynamic loader's search; on "
    "macOS python.org's, Homebrew's, conda's active environment, pyenv's, Xcode's, then the dynamic "
    "loader's search; on Windows the PEP 514 registrations and PATH). If none serves, instantiation fails "
    "with one message naming every place it looked.")


def bundled_requirements(runtimes: dict, folders: dict, licences: dict, others: list) -> str:
    """``REQUIREMENTS`` of an FMU that carries ``runtimes`` (by platform, each in ``folders`` with ``licences``)
    and none for the ``others``."""
    carried = "; ".join(
        f"for {platform} CPython {runtime.version} in {folders[platform]}"
        + (f" (it needs {', '.join(runtime.needs)})" if runtime.needs else "")
        + f", licences in {', '.join(licences[platform])}"
        for platform, runtime in sorted(runtimes.items()))
    elsewhere = (f" On {', '.join(others)} it carries none and needs the importing machine's 64-bit CPython 3.9 or "
                 "newer, as an FMU without one does." if others else "")
    return ("The FMU needs no execution tool (needsExecutionTool = false) and no Python on the importing machine "
            f"where it carries one: it carries the model, the Python code that runs it and a CPython to run it "
            f"({carried}). The binary uses a CPython already in the process (one per process), else the one "
            "DSC_FMU_PYTHON names, else the FMU's own, which starts isolated (PYTHON* variables and user "
            "site-packages ignored, no bytecode written). A damaged runtime fails instantiation with one message "
            f"naming it and what failed.{elsewhere}")


_STYLE = "body{font-family:sans-serif;max-width:60em}table{border-collapse:collapse}td,th{border:1px solid #999;padding:2px 6px}"


def documentation_html(model_description: ET.Element, name: str, units: dict[str, str],
                       requirements: str = REQUIREMENTS) -> str:
    """The HTML page of FMU ``name`` from its completed model description: its interfaces, equations,
    variables (``units`` where the model description gives none), default experiment and requirements."""
    root = model_description
    version = root.get("fmiVersion")
    rows = []
    for variable in _variables(root):
        typed = variable[0] if version.startswith("2") else variable
        start = typed.get("start", "")
        unit = typed.get("unit") or units.get(variable.get("name"), "")
        cells = (variable.get("name"), variable.get("causality", "local"), variable.get("variability", "continuous"),
                 start, unit, variable.get("description", ""))
        rows.append("<tr>" + "".join(f"<td>{escape(str(c))}</td>" for c in cells) + "</tr>")
    experiment = root.find("DefaultExperiment")
    experiment_text = ", ".join(f"{key} = {value}" for key, value in experiment.attrib.items()) if experiment is not None else "none"
    return "\n".join([
        "<!DOCTYPE html>",
        '<html lang="en">',
        f"<head><meta charset=\"utf-8\"/><title>{escape(name)}</title><style>{_STYLE}</style></head>",
        "<body>",
        f"<h1>{escape(name)}</h1>",
        f"<p>{escape(root.get('description', ''))}.</p>",
        f"<p>FMI {escape(version)} FMU for {escape(_interfaces(root))}, built by dsc-fmu "
        f"({escape(root.get('generationTool', ''))}). It implements part of {escape(PAPER)}</p>",
        "<h2>Equations</h2>",
        f"<pre>{escape(EQUATIONS[name])}</pre>",
        "<h2>Variables</h2>",
        "<table>",
        "<tr><th>name</th><th>causality</th><th>variability</th><th>start</th><th>unit</th><th>description</th></tr>",
        *rows,
        "</table>",
        "<h2>Default experiment</h2>",
        f"<p>{escape(experiment_text)} (times in s)</p>",
        "<h2>Requirements</h2>",
        f"<p>{escape(requirements)}</p>",
        "</body>",
        "</html>",
        "",
    ])


def _interfaces(root: ET.Element) -> str:
    names = [words for tag, words in (("ModelExchange", "model exchange"), ("CoSimulation", "co-simulation"))
             if root.find(tag) is not None]
    return " and ".join(names)


def _variables(root: ET.Element) -> list[ET.Element]:
    variables = root.find("ModelVariables")
    return list(variables) if variables is not None else []
