"""The inputs the slave tests drive the FMUs with, in this process (``in_process``) and through the binary.

The paper's parameters (``PLANT``, ``CONTROLLER``); controller inputs are in the order of
``CONTROLLER_IN``; ``DRIVES`` gives each FMU a short drive that
changes its outputs (the controller's crosses the beta guard); ``replay`` records one.
"""

import math

from dsc_fmu.models import parameters as P

__all__ = ["CONTROLLER", "CONTROLLER_IN", "DRIVES", "M_GUARD", "M_OTHER", "M_PAPER", "NAMES", "PLANT", "PLANT_OUT",
           "replay"]

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
PLANT = P.defaults(P.PLANT_PARAMETERS)
CONTROLLER = P.defaults(P.CONTROLLER_PARAMETERS)
PLANT_OUT = tuple(v.name for v in P.PLANT_OUTPUTS)
CONTROLLER_IN = tuple(v.name for v in P.CONTROLLER_INPUTS)
# Measurements at the paper's initial condition (robot at (2.5, 1, pi/2), reference at (2, 2, 0)).
M_PAPER = [2.5, 1.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]
M_OTHER = [2.4, 1.1, 1.4, 0.1, 0.5, 0.4, 0.2, 0.1, 2.05, 2.0, 0.02, 0.9, 0.25, 0.1]
# Robot 1 m ahead of the reference on its heading: S11 = -1, beta = 1 - k1 vr = -1 < beta_min.
M_GUARD = [3.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.2, 0.0]
# Each FMU: its Integer parameters, the inputs set at each step and their values at step k.
DRIVES = {
    "ReferenceRobot": ({"profile": 1}, [], lambda k: []),
    "MobileRobot": ({}, ["u1", "u2"], lambda k: [10.0 + k, 8.0 - 0.5 * k]),
    "DSCController": ({}, list(CONTROLLER_IN), lambda k: [m + 0.01 * k for m in M_GUARD]),
}


def replay(instance, inputs, schedule, t0, steps, h):
    """Every output before each of ``steps`` steps of ``h`` from ``t0`` and after the last; ``schedule``
    gives the ``inputs`` at each step."""
    rows = []
    for k in range(steps):
        if inputs:
            instance.set(inputs, schedule(k))
        rows.append(instance.outputs())
        instance.step(t0 + k * h, h)
    rows.append(instance.outputs())
    return rows
