"""The step-size study's linearised loop from the FMUs' exact directional derivatives (``linearise(...,
source="fmus")``): the controller's and the plant's matrices in error coordinates."""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from ..cosim.instance import LoadedFmu
from ..cosim.linear import Blocks, fmu_blocks
from ..cosim.loading import LoadedFmus
from ..models.plant import plant_coefficients
from ..registry import ORDER
from ..scenario import Scenario
from .tracking import MEASUREMENT_SELECTION, error_measurements, error_outputs

__all__ = ["fmu_matrices"]


def _settle(fmu: LoadedFmu) -> None:
    """In event mode: update the discrete states (the switches) until none needs more, then enter
    continuous-time mode."""
    while fmu.update_discrete_states()[0]:
        pass
    fmu.call(fmu.instance.enterContinuousTimeMode)


def _at_point(fmu: LoadedFmu, scenario: Scenario, t: float, states, inputs: dict) -> LoadedFmu:
    """A model-exchange FMU with the scenario's parameters in continuous-time mode at time ``t``, its
    continuous states and inputs set, its switches chosen there (an event iteration at the point)."""
    fmu.enter_initialization(None, scenario.parameters(fmu.name))
    fmu.set_values(inputs)
    fmu.call(fmu.instance.exitInitializationMode)
    _settle(fmu)
    fmu.call(fmu.instance.setTime, t)
    values = (ctypes.c_double * len(states))(*states)
    fmu.call(fmu.instance.setContinuousStates, values, len(states))
    fmu.set_values(inputs)
    fmu.call(fmu.instance.enterEventMode)
    _settle(fmu)
    return fmu


def _error_plant(reference: Blocks, plant: Blocks, w: float, S11: float, S12: float) -> tuple:
    """``(Ap, Bp, Cp)`` in error coordinates from the reference's and the plant's world blocks.

    Eq. (10) at the robot at the origin heading 0 (``error_measurements``) is ``S = Phi(p, r)`` with
    ``Phi(0, r) = r``; eq. (11) is ``S' = Phi_p(p, r) p' + Phi_r(p, r) r'`` and, being invariant under
    rigid motions, a function of ``S`` alone, so its Jacobian is the derivative along ``p = 0, r = S``:
    ``(d Phi_p / d r) p' + Phi_r (d r' / d r)`` on the pose (``Phi_r = I``, ``d r' / d r`` the
    ReferenceRobot's A at ``r = S``; ``d Phi_p / d r`` leaves ``theta_dot`` = ``w`` at (S11, S12) and
    ``-w`` at (S12, S11)), ``Phi_p (d p' / d v)`` on the wheel speeds with the MobileRobot's kinematic
    entries (1) and ``Phi_p = [[-1, 0, S12], [0, -1, -S11], [0, 0, -1]]``. The rows and columns of eqs.
    (7), (8) and the plant's outputs are the FMU's own (the pose enters none of them). Exact: no
    differences, no row taken from the Python model.
    """
    A, B = plant.A, plant.B
    Phi_p = np.array([[-1.0, 0.0, S12], [0.0, -1.0, -S11], [0.0, 0.0, -1.0]])
    Ap, Bp, Cp = np.zeros((7, 7)), np.zeros((7, 2)), np.zeros((8, 7))
    Ap[:3, :3] = reference.A + np.array([[0.0, w, 0.0], [-w, 0.0, 0.0], [0.0, 0.0, 0.0]])
    Ap[:3, 3:], Bp[:3] = Phi_p @ A[:3, 3:], Phi_p @ B[:3]
    Ap[3:, 3:], Bp[3:] = A[3:, 3:], B[3:]
    Cp[:3, :3] = np.eye(3)
    Cp[3:, 3:] = plant.C[:, 3:]
    return Ap, Bp, Cp


def fmu_matrices(scenario: Scenario, fmu_paths: dict, z, at_time: float, workdir: Path | None = None) -> tuple:
    """The loop's matrices in error coordinates from the FMUs' exact directional derivatives.

    The three FMUs are loaded for model exchange with the scenario's parameters, put at the operating
    point ``z`` (robot at the origin heading 0, reference at (S11, S12, S13bar): ``error_measurements``)
    and linearised (``cosim.linear.fmu_blocks``). The controller (15)-(27): ``Ac``, ``Cc`` are its own,
    ``Bc = B E`` and ``Dc = D E`` with ``E = MEASUREMENT_SELECTION``. The plant (7), (8), (11): see
    ``_error_plant``; the plant's voltages are the controller's outputs there.

    Parameters
    ----------
    scenario : Scenario
        A scenario with the constant reference profile (``linearise`` checks it).
    fmu_paths : dict
        The three FMU files by name, with model exchange.
    z : array_like
        ``[xp; xc]`` (27) in error coordinates (``operating_point``).
    at_time : float
        The FMUs' time, in s.
    workdir : pathlib.Path or None, optional
        Where they are extracted. Default None: the system's temporary folder.

    Returns
    -------
    tuple of numpy.ndarray
        ``(Ap, Bp, Cp, Ac, Bc, Cc, Dc)`` as ``LinearLoop`` takes them.
    """
    vr, wr = scenario.reference["vr0"], scenario.reference["wr0"]
    z = np.asarray(z, float)
    xp, xc = z[:7], z[7:]
    m = error_measurements(error_outputs(plant_coefficients(scenario.plant), xp), vr, wr)
    with LoadedFmus(fmu_paths, workdir, [], model_exchange=True) as fmus:
        reference, plant, controller = (fmus.by_name[name] for name in ORDER)
        _at_point(controller, scenario, at_time, xc, dict(zip(controller.real_inputs, m)))
        voltages = controller.get_values(plant.real_inputs)
        kc = fmu_blocks(controller, controller.real_inputs, plant.real_inputs)
        _at_point(plant, scenario, at_time, [0.0, 0.0, 0.0, *xp[3:]], voltages)
        kp = fmu_blocks(plant, plant.real_inputs, ["theta_dot", *plant.state_names[3:]])
        w = plant.get_values(["theta_dot"])["theta_dot"]
        kr = fmu_blocks(_at_point(reference, scenario, at_time, xp[:3], {}), [], [])
    E = MEASUREMENT_SELECTION
    return (*_error_plant(kr, kp, w, xp[0], xp[1]), kc.A, kc.B @ E, kc.C, kc.D @ E)
