"""The dependencies of ModelStructure, found by running the model code that the FMU runs.

An unknown (an output, a state derivative, an initial value) depends on a known (an input, a state, the
time, a parameter at initialization) if changing the known changes it: each unknown is evaluated at random
points, each known changed in turn, for every value of the parameters that choose between laws and with the
switches chosen at each point or held in each of the model's ``BRANCHES``; at a random point a dependency
shows as a changed value, and its absence leaves the value exactly as it was.
"""

from __future__ import annotations

import itertools
import random

from ..fmu.controller_model import DSCControllerModel
from ..fmu.robot_models import MobileRobotModel, ReferenceRobotModel
from ..registry import FmuSpec

__all__ = ["TIME"]

TIME = "time"
_POINTS = 3
_SEED = 20260917
_MODELS = {"MobileRobot": MobileRobotModel, "ReferenceRobot": ReferenceRobotModel, "DSCController": DSCControllerModel}


class _Probe:
    """A model with the values a slave would hand it: inputs ``u``, ``state`` and ``time``."""

    def __init__(self, model):
        self.model, self.p = model, model.p
        self.u = [v.start for v in model.INPUTS]
        self.state = None
        self.time = 0.0


def _models(spec: FmuSpec):
    """A probe of ``spec``'s model for every combination of the parameters that choose between laws, and of
    the switches it holds (its ``BRANCHES``)."""
    choosers = [v for v in spec.parameters if v.choices]
    model_class = _MODELS[spec.name]
    for values in itertools.product(*(range(len(v.choices)) for v in choosers)):
        for held in model_class.BRANCHES:
            probe = _Probe(model_class())
            probe.p.update({v.name: value for v, value in zip(choosers, values)})
            if held is not None:
                probe.model.held = held
            yield probe


def _changed(value: float) -> float:
    return value + 1e-3 * max(1.0, abs(value))


def _dependencies(spec: FmuSpec, knowns: dict, evaluate) -> dict[str, tuple[str, ...]]:
    """For each unknown ``evaluate(probe)`` returns, the knowns (the inputs, ``knowns``: name -> ``(get, set)``, and
    ``TIME``) whose change changes it."""
    knowns = {**{v.name: (lambda probe, i=i: probe.u[i], _setter("u", i)) for i, v in enumerate(spec.inputs)}, **knowns,
              TIME: (lambda probe: probe.time, lambda probe, value: setattr(probe, "time", value))}
    rng = random.Random(_SEED)
    found = {}
    for probe in _models(spec):
        for _ in range(_POINTS):
            probe.p.update({v.name: (v.start or 1.0) * rng.uniform(0.5, 2.0) for v in spec.parameters if not v.integer})
            probe.model.parameters_changed()
            probe.u = [rng.uniform(0.5, 2.0) for _ in probe.u]
            probe.state = [rng.uniform(0.5, 2.0) for _ in spec.states]
            probe.time = rng.uniform(0.5, 2.0)
            base = evaluate(probe)
            for name, (get, put) in knowns.items():
                before = get(probe)
                put(probe, _changed(before))
                after = evaluate(probe)
                put(probe, before)
                for unknown, value in base.items():
                    found.setdefault(unknown, set())
                    if after[unknown] != value:
                        found[unknown].add(name)
    order = list(knowns)
    return {unknown: tuple(sorted(names, key=order.index)) for unknown, names in found.items()}


def _setter(attribute: str, key):
    def put(probe, value):
        getattr(probe, attribute)[key] = value
        probe.model.parameters_changed()
    return put


def _continuous(probe) -> dict:
    model, x = probe.model, probe.state
    values = dict(zip((v.name for v in model.OUTPUTS), model.outputs(probe.time, x, probe.u)))
    values.update(zip((s.derivative.name for s in model.STATES), model.rates(probe.time, x, probe.u)))
    values.update(zip((v.name for v in model.INDICATORS), model.indicators(x, probe.u)))
    return values


def continuous_dependencies(spec: FmuSpec) -> dict[str, tuple[str, ...]]:
    """Each continuous output, state derivative and event indicator -> its inputs, states and ``TIME``, in
    continuous-time mode (and at communication points)."""
    states = {s.variable.name: (lambda probe, i=i: probe.state[i], _setter("state", i))
              for i, s in enumerate(spec.states)}
    return _dependencies(spec, states, _continuous)


def _initial(probe) -> dict:
    model = probe.model
    x = model.initial_state(probe.u)
    values = dict(zip((v.name for v in model.OUTPUTS), model.outputs(probe.time, x, probe.u)))
    values.update(zip((s.variable.name for s in model.STATES), x))
    values.update(zip((s.derivative.name for s in model.STATES), model.rates(probe.time, x, probe.u)))
    return values


def initial_dependencies(spec: FmuSpec) -> dict[str, tuple[str, ...]]:
    """Each continuous output, state and state derivative -> its inputs, Real parameters and ``TIME``, in
    initialization mode."""
    parameters = {v.name: (lambda probe, n=v.name: probe.p[n], _setter("p", v.name)) for v in spec.parameters
                  if not v.integer}
    return _dependencies(spec, parameters, _initial)
