"""The dependencies of ModelStructure, found by running the model code that the FMU runs.

An unknown (an output, a state derivative, an initial value) depends on a known (an input, a state, the
time, a parameter at initialization) if changing the known changes it: each unknown is evaluated at random
points, each known changed in turn, for every value of the parameters that choose between laws; at a random
point a dependency shows as a changed value, and its absence leaves the value exactly as it was.
"""

from __future__ import annotations

import itertools
import random

from ..fmu import slave_models
from ..fmu.slave_core import SlaveCore
from ..registry import FmuSpec

__all__ = ["TIME", "continuous_dependencies", "initial_dependencies"]

TIME = "time"
_POINTS = 3
_SEED = 20260917


class _Bare(SlaveCore):
    """A slave without an FMI library: the model code and nothing else."""

    instance_name = "structure"

    def __init__(self):
        self._init_core()

    def _register(self, v, causality, getter, setter=None):
        pass

    def register_discrete_output(self, name, description, getter, boolean):
        pass


def _models(spec: FmuSpec):
    """A bare slave of ``spec``'s model for every combination of the parameters that choose between laws."""
    model = getattr(slave_models, f"{spec.name}Model")
    probe_class = type(f"{spec.name}Structure", (model, _Bare), {})
    choosers = [v for v in spec.parameters if v.choices]
    for values in itertools.product(*(range(len(v.choices)) for v in choosers)):
        probe = probe_class()
        probe.p.update({v.name: value for v, value in zip(choosers, values)})
        yield probe


def _changed(value: float) -> float:
    return value + 1e-3 * max(1.0, abs(value))


def _dependencies(spec: FmuSpec, knowns: dict, evaluate) -> dict[str, tuple[str, ...]]:
    """For each unknown ``evaluate(probe)`` returns, the ``knowns`` (name -> ``(get, set)``) whose change changes it."""
    rng = random.Random(_SEED)
    found = {}
    for probe in _models(spec):
        for _ in range(_POINTS):
            probe.p.update({v.name: (v.start or 1.0) * rng.uniform(0.5, 2.0) for v in spec.parameters if not v.integer})
            probe._stale(parameters=True)
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
        probe._stale(parameters=True)
    return put


def _continuous(probe) -> dict:
    x = probe.state
    values = dict(zip((v.name for v in probe.OUTPUTS), probe.outputs(x)))
    values.update(zip((s.derivative.name for s in probe.STATES), probe.derivatives(probe.time, x)))
    values.update(zip((v.name for v in probe.INDICATORS), probe.indicator_values(x)))
    return values


def continuous_dependencies(spec: FmuSpec) -> dict[str, tuple[str, ...]]:
    """The dependencies in continuous-time mode (and at communication points).

    Parameters
    ----------
    spec : registry.FmuSpec
        The FMU.

    Returns
    -------
    dict of str to tuple of str
        Each continuous output, state derivative and event indicator -> its inputs, states and ``TIME``.
    """
    knowns = {v.name: (lambda probe, i=i: probe.u[i], _setter("u", i)) for i, v in enumerate(spec.inputs)}
    knowns.update({s.variable.name: (lambda probe, i=i: probe.state[i], _setter("state", i))
                   for i, s in enumerate(spec.states)})
    knowns[TIME] = (lambda probe: probe.time, lambda probe, value: setattr(probe, "time", value))
    return _dependencies(spec, knowns, _continuous)


def _initial(probe) -> dict:
    probe.state = None
    x = probe.current_state()
    values = dict(zip((v.name for v in probe.OUTPUTS), probe.outputs(x)))
    values.update(zip((s.variable.name for s in probe.STATES), x))
    values.update(zip((s.derivative.name for s in probe.STATES), probe.derivatives(probe.time, x)))
    return values


def initial_dependencies(spec: FmuSpec) -> dict[str, tuple[str, ...]]:
    """The dependencies in initialization mode.

    Parameters
    ----------
    spec : registry.FmuSpec
        The FMU.

    Returns
    -------
    dict of str to tuple of str
        Each continuous output, state and state derivative -> its inputs, Real parameters and ``TIME``.
    """
    knowns = {v.name: (lambda probe, i=i: probe.u[i], _setter("u", i)) for i, v in enumerate(spec.inputs)}
    knowns.update({v.name: (lambda probe, n=v.name: probe.p[n], _setter("p", v.name))
                   for v in spec.parameters if not v.integer})
    knowns[TIME] = (lambda probe: probe.time, lambda probe, value: setattr(probe, "time", value))
    return _dependencies(spec, knowns, _initial)
