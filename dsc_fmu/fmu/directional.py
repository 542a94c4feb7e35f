"""Exact directional and adjoint derivatives of a slave (fmi2GetDirectionalDerivative,
fmi3GetDirectionalDerivative, fmi3GetAdjointDerivative): forward-mode automatic differentiation on dual
numbers (``models.dual``) of the same ``rates`` and ``outputs`` that compute the values.

Bundled into every FMU; imports only the standard library and ``models``.
"""

from __future__ import annotations

import math

from ..models.dual import Dual

__all__ = []  # ``slave.ModelSlave`` uses what is here

# The roles of a Real variable: unknowns (state derivatives, outputs), knowns (states, inputs).
DERIVATIVE, OUTPUT, STATE, INPUT = "derivative", "output", "state", "input"
# What directional derivatives allow, by (model exchange, unknown): the roles and their words.
_ALLOWED = {
    (True, True): ((DERIVATIVE, OUTPUT), "state derivatives and Real outputs"),
    (True, False): ((STATE, INPUT), "continuous states and Real inputs"),
    (False, True): ((OUTPUT,), "Real outputs"),
    (False, False): ((INPUT,), "Real inputs"),
}


class Roles:
    """The role and index of each Real state, state derivative, output and input of a slave, by value reference
    (``variables``: pythonfmu's ``vars``; ``owner``: the slave class's name, for messages).
    """

    def __init__(self, model, variables: dict, owner: str):
        positions = {}
        tables = ((DERIVATIVE, [s.derivative for s in model.STATES]), (STATE, [s.variable for s in model.STATES]),
                  (OUTPUT, model.OUTPUTS), (INPUT, model.INPUTS))
        for role, table in tables:
            for index, v in enumerate(table):
                positions.setdefault(v.name, {})[role] = index
        self._roles = {r: positions[v.name] for r, v in variables.items() if v.name in positions}
        self._variables = variables
        self._owner = owner
        self._resolved = {}

    def resolve(self, references: list, model_exchange: bool, unknown: bool) -> list:
        """The ``(role, index)`` of each value reference as an unknown (else a known) of model exchange (else
        co-simulation): one of ``DERIVATIVE``, ``OUTPUT``, ``STATE``, ``INPUT`` and the position in its table.
        Remembered for the last 64 lists (an importer asks with the same lists again). ValueError naming the first
        reference that is not an allowed unknown or known, and what is allowed.
        """
        key = (tuple(references), model_exchange, unknown)
        found = self._resolved.get(key)
        if found is None:
            found = [self._role(int(r), model_exchange, unknown) for r in references]
            if len(self._resolved) >= 64:
                self._resolved.clear()
            self._resolved[key] = found
        return found

    def _role(self, reference: int, model_exchange: bool, unknown: bool) -> tuple:
        roles = self._roles.get(reference, {})
        allowed, words = _ALLOWED[model_exchange, unknown]
        for role in allowed:
            if role in roles:
                return role, roles[role]
        v = self._variables.get(reference)
        interface = "model exchange" if model_exchange else "co-simulation"
        what = (f"is not a variable of {self._owner}" if v is None else
                f"({v.name}) is {_what(v, roles)}, not {'an unknown' if unknown else 'a known'} of {interface}")
        raise ValueError(f"value reference {reference} {what}; allowed {'unknowns' if unknown else 'knowns'}: {words}")


def directional(forward, rows: list, columns: list, seed: list) -> list:
    """``J seed`` for the unknowns ``rows`` and knowns ``columns`` of ``Roles.resolve``, in one forward pass:
    ``forward(rows, direction)`` gives the tangents of the unknowns on duals seeded by ``direction`` (role ->
    {index: seed}). ValueError unless ``seed`` has one entry per known."""
    _check_count(seed, columns, "knowns")
    direction = {STATE: {}, INPUT: {}}
    for (role, index), value in zip(columns, seed):
        direction[role][index] = direction[role].get(index, 0.0) + float(value)
    return forward(rows, direction)


def adjoint(forward, rows: list, columns: list, seed: list) -> list:
    """``seed^T J``, J as in ``directional``: one forward pass per distinct known. ValueError unless ``seed`` has
    one entry per unknown."""
    _check_count(seed, rows, "unknowns")
    weights = [float(value) for value in seed]
    found = {}
    for role, index in columns:
        if (role, index) not in found:
            column = forward(rows, {STATE: {}, INPUT: {}, role: {index: 1.0}})
            found[role, index] = math.fsum(w * d for w, d in zip(weights, column))
    return [found[column] for column in columns]


def seeded(values: list, seeds: dict) -> list:
    """``values`` with a ``Dual`` for each entry of nonzero seed (``seeds``: index -> seed); only those become
    duals, so that what does not depend on them is computed on floats."""
    if not seeds:
        return values
    values = list(values)
    for index, seed in seeds.items():
        if seed:
            values[index] = Dual(values[index], seed)
    return values


def _what(v, roles: dict) -> str:
    """What the variable ``v`` with ``roles`` is, for a message: "a continuous state and a Real output"."""
    kind = f"{'an' if type(v).__name__[0] in 'AEIOU' else 'a'} {type(v).__name__}"
    names = {DERIVATIVE: "a state derivative", STATE: "a continuous state", OUTPUT: f"{kind} output",
             INPUT: f"{kind} input"}
    what = " and ".join(names[role] for role in names if role in roles)
    return what or f"{kind} {v.causality.name}"


def _check_count(seed: list, references: list, what: str) -> None:
    if len(seed) != len(references):
        entries = "entry" if len(seed) == 1 else "entries"
        raise ValueError(
            f"the seed has {len(seed)} {entries} for {len(references)} {what}; allowed: one per {what[:-1]}")
