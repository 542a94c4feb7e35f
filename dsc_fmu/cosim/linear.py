"""The FMUs linearised through their exact directional derivatives (``fmi2GetDirectionalDerivative``,
``fmi3GetDirectionalDerivative``): each FMU's ``A, B, C, D`` at its current point, the Jacobian of the
three as one ODE (model exchange's loop), and python-control state-space models of either (python-control
imported only when one is asked for: a run needs none)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..registry import ORDER
from .instance import LoadedFmu

if TYPE_CHECKING:
    import control

__all__: list[str] = []  # the package's own: Blocks, fmu_blocks, loop_jacobian, closed_loop_state_space


@dataclass(frozen=True)
class Blocks:
    """One FMU linearised: ``x' = A x + B u``, ``y = C x + D u`` in deviations from its current point, with the
    names of its states, inputs and outputs in the matrices' order."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: tuple
    inputs: tuple
    outputs: tuple

    def state_space(self) -> control.StateSpace:
        """The FMU as a python-control ``ss(A, B, C, D)``, its signals named."""
        import control

        return control.ss(self.A, self.B, self.C, self.D, states=list(self.states), inputs=list(self.inputs),
                          outputs=list(self.outputs))


def _columns(fmu: LoadedFmu, unknowns: list[int], knowns: list[int]) -> np.ndarray:
    """The Jacobian ``d unknowns / d knowns`` at the FMU's current point, a column per known (a unit seed
    each: one directional derivative per column)."""
    jacobian = np.zeros((len(unknowns), len(knowns)))
    for j in range(len(knowns)):
        seed = [0.0] * len(knowns)
        seed[j] = 1.0
        jacobian[:, j] = fmu.call(fmu.instance.getDirectionalDerivative, unknowns, knowns, seed)
    return jacobian


def fmu_blocks(fmu: LoadedFmu, inputs: list[str] | None = None, outputs: list[str] | None = None) -> Blocks:
    """A model-exchange FMU (in event or continuous-time mode) linearised at its current point from its
    directional derivatives; ``inputs``, ``outputs``: the Real ones to take (default: all)."""
    inputs = list(fmu.real_inputs if inputs is None else inputs)
    outputs = list(fmu.real_outputs if outputs is None else outputs)
    n = len(fmu.state_refs)
    unknowns = [*fmu.derivative_refs, *fmu.refs(outputs)]
    jacobian = _columns(fmu, unknowns, [*fmu.state_refs, *fmu.refs(inputs)])
    return Blocks(jacobian[:n, :n], jacobian[:n, n:], jacobian[n:, :n], jacobian[n:, n:],
                  tuple(fmu.state_names), tuple(inputs), tuple(outputs))


def loop_jacobian(reference: Blocks, plant: Blocks, controller: Blocks) -> np.ndarray:
    """The Jacobian ``d z' / d z`` of the closed loop's ODE, ``z = [reference; plant; controller]``.

    The controller measures the outputs its inputs name; the plant's inputs are the controller's outputs of the
    same names. The plant has no direct feedthrough, so there is no algebraic loop: ``du/dz = Cc dxc/dz + Dc dm/dz``
    with ``dm/dz`` from the plant's and the reference's C. ValueError if the plant's D is not zero."""
    if plant.D.any():
        raise ValueError("the plant's outputs depend on its inputs (D is not zero): the loop would be algebraic")
    nr, npl, nc = len(reference.states), len(plant.states), len(controller.states)
    n = nr + npl + nc
    rows = {name: (reference, i) for i, name in enumerate(reference.outputs)}
    rows.update({name: (plant, i) for i, name in enumerate(plant.outputs)})
    dm = np.zeros((len(controller.inputs), n))  # the measurements against the loop's state
    for k, name in enumerate(controller.inputs):
        source, i = rows[name]
        start = 0 if source is reference else nr
        dm[k, start:start + len(source.states)] = source.C[i]
    voltages = [controller.outputs.index(name) for name in plant.inputs]
    du = controller.D[voltages] @ dm
    du[:, nr + npl:] += controller.C[voltages]
    jacobian = np.zeros((n, n))
    jacobian[:nr, :nr] = reference.A
    jacobian[nr:nr + npl, nr:nr + npl] = plant.A
    jacobian[nr:nr + npl] += plant.B @ du
    jacobian[nr + npl:, nr + npl:] = controller.A
    jacobian[nr + npl:] += controller.B @ dm
    return jacobian


def closed_loop_state_space(blocks: dict) -> control.StateSpace:
    """The closed loop linearised as a python-control ``ss(A, B, C, 0)`` from the three FMUs' ``blocks`` (by
    name, in model exchange's order): states ``<FMU>.<state>``, A the loop's Jacobian, inputs disturbances
    ``d_u1``, ``d_u2`` added to the plant's inputs, outputs the plant's outputs the controller measures."""
    import control

    reference, plant, controller = (blocks[name] for name in ORDER)
    nr, npl = len(reference.states), len(plant.states)
    n = nr + npl + len(controller.states)
    B = np.zeros((n, len(plant.inputs)))
    B[nr:nr + npl] = plant.B
    C = np.zeros((len(plant.outputs), n))
    C[:, nr:nr + npl] = plant.C
    states = [f"{name}.{state}" for name, b in blocks.items() for state in b.states]
    return control.ss(loop_jacobian(reference, plant, controller), B, C, np.zeros((len(plant.outputs), len(plant.inputs))),
                      states=states, inputs=[f"d_{name}" for name in plant.inputs], outputs=list(plant.outputs))
