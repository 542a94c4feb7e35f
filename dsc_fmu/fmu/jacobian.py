"""Exact directional and adjoint derivatives of a slave (fmi2GetDirectionalDerivative,
fmi3GetDirectionalDerivative, fmi3GetAdjointDerivative): forward-mode automatic differentiation, on dual
numbers (``models.dual``), of the same ``rates`` and ``outputs`` that compute the values.

Bundled into every FMU beside ``slave_core``; ``SlaveCore`` inherits ``DirectionalDerivatives``.
"""

from __future__ import annotations

import math

from ..models.dual import DUAL_MATH, Dual, tangent

__all__ = ["DirectionalDerivatives"]

# The roles of a Real variable in a Jacobian: unknowns (derivatives, outputs), knowns (states, inputs).
DERIVATIVE, OUTPUT, STATE, INPUT = "derivative", "output", "state", "input"
# What directional derivatives allow, by (model exchange, unknown): the roles and their words.
_ALLOWED = {
    (True, True): ((DERIVATIVE, OUTPUT), "state derivatives and Real outputs"),
    (True, False): ((STATE, INPUT), "continuous states and Real inputs"),
    (False, True): ((OUTPUT,), "Real outputs"),
    (False, False): ((INPUT,), "Real inputs"),
}


class DirectionalDerivatives:
    """The derivatives of a slave's unknowns by its knowns, by value reference.

    A mixin of ``SlaveCore``, whose ``rates``, ``outputs``, ``state_at``, ``current_state``, ``u``,
    ``time``, ``vars``, ``STATES``, ``OUTPUTS`` and ``INPUTS`` it reads, and whose ``_roles`` and
    ``_resolved`` it keeps.
    """

    def directional_derivative(self, unknowns: list, knowns: list, seed: list, model_exchange: bool) -> list:
        """``J seed``, J the Jacobian of the unknowns by the knowns here (fmi2/fmi3GetDirectionalDerivative).

        Model exchange: at the time, continuous state and inputs set, with the switches held
        (docs/model.md §5.13); unknowns are state derivatives and Real outputs, knowns continuous
        states and Real inputs. Co-simulation: at the current state and inputs, the switches as the
        law chooses them there, the state following the inputs until the first step (§5.2);
        unknowns are Real outputs, knowns Real inputs. One forward pass on dual numbers.

        Parameters
        ----------
        unknowns : list of int
            The value references of the unknowns.
        knowns : list of int
            The value references of the knowns.
        seed : list of float
            One entry per known: the direction.
        model_exchange : bool
            Whether the instance is one of model exchange.

        Returns
        -------
        list of float
            One entry per unknown: its derivative along ``seed``.

        Raises
        ------
        ValueError
            For a reference that is not an allowed unknown or known, or a ``seed`` whose length differs
            from that of ``knowns``.
        """
        rows, columns = self._resolve(unknowns, model_exchange, True), self._resolve(knowns, model_exchange, False)
        _check_count(seed, knowns, "knowns")
        direction = {STATE: {}, INPUT: {}}
        for (role, index), value in zip(columns, seed):
            direction[role][index] = direction[role].get(index, 0.0) + float(value)
        return self._forward(rows, direction, model_exchange)

    def adjoint_derivative(self, unknowns: list, knowns: list, seed: list, model_exchange: bool) -> list:
        """``seed^T J``, J as in ``directional_derivative`` (fmi3GetAdjointDerivative): one forward pass per known.

        Parameters
        ----------
        unknowns : list of int
            The value references of the unknowns.
        knowns : list of int
            The value references of the knowns.
        seed : list of float
            One entry per unknown.
        model_exchange : bool
            Whether the instance is one of model exchange.

        Returns
        -------
        list of float
            One entry per known: ``sum_i seed_i d unknown_i / d known``.

        Raises
        ------
        ValueError
            As ``directional_derivative``, with ``seed`` one entry per unknown.
        """
        rows, columns = self._resolve(unknowns, model_exchange, True), self._resolve(knowns, model_exchange, False)
        _check_count(seed, unknowns, "unknowns")
        weights = [float(value) for value in seed]
        found = {}
        for role, index in columns:
            if (role, index) not in found:
                column = self._forward(rows, {STATE: {}, INPUT: {}, role: {index: 1.0}}, model_exchange)
                found[role, index] = math.fsum(w * d for w, d in zip(weights, column))
        return [found[column] for column in columns]

    def _forward(self, rows: list, direction: dict, model_exchange: bool) -> list:
        """The tangents of the unknowns ``rows`` ((role, index) pairs) along ``direction`` (role -> {index: seed}).

        Only the knowns with a seed become duals: what does not depend on them is computed on floats."""
        u = _seeded(self.u, direction[INPUT])
        if model_exchange:
            x = _seeded(self.current_state(), direction[STATE])
        else:
            x = self.state_at(u, DUAL_MATH)
        roles = {role for role, _ in rows}
        values = {
            DERIVATIVE: self.rates(self.time, x, u, DUAL_MATH) if DERIVATIVE in roles else None,
            OUTPUT: self.outputs(x, u, DUAL_MATH) if OUTPUT in roles else None,
        }
        return [tangent(values[role][index]) for role, index in rows]

    def _resolve(self, references: list, model_exchange: bool, unknown: bool) -> list:
        """The (role, index) of each reference as an unknown or a known; ValueError naming the first not allowed.

        Remembered for the last few lists of references (an importer asks with the same lists again)."""
        key = (tuple(references), model_exchange, unknown)
        found = self._resolved.get(key)
        if found is None:
            found = [self._role(int(r), model_exchange, unknown) for r in references]
            if len(self._resolved) >= 64:
                self._resolved.clear()
            self._resolved[key] = found
        return found

    def _role(self, reference: int, model_exchange: bool, unknown: bool) -> tuple:
        """(role, index) of the value reference ``reference`` as an unknown or a known."""
        roles = self._real_roles().get(reference, {})
        allowed, words = _ALLOWED[model_exchange, unknown]
        for role in allowed:
            if role in roles:
                return role, roles[role]
        v = self.vars.get(reference)
        interface = "model exchange" if model_exchange else "co-simulation"
        what = (f"is not a variable of {type(self).__name__}" if v is None else
                f"({v.name}) is {_what(v, roles)}, not {'an unknown' if unknown else 'a known'} of {interface}")
        raise ValueError(f"value reference {reference} {what}; allowed {'unknowns' if unknown else 'knowns'}: {words}")

    def _real_roles(self) -> dict:
        """Value reference -> {role: index} of every Real state, state derivative, output and input."""
        if self._roles is None:
            positions = {}
            tables = ((DERIVATIVE, [s.derivative for s in self.STATES]), (STATE, [s.variable for s in self.STATES]),
                      (OUTPUT, self.OUTPUTS), (INPUT, self.INPUTS))
            for role, table in tables:
                for index, v in enumerate(table):
                    positions.setdefault(v.name, {})[role] = index
            self._roles = {r: positions[v.name] for r, v in self.vars.items() if v.name in positions}
        return self._roles


def _what(v, roles: dict) -> str:
    """What the variable ``v`` with ``roles`` is, for a message: "a continuous state and a Real output"."""
    kind = f"{'an' if type(v).__name__[0] in 'AEIOU' else 'a'} {type(v).__name__}"
    names = {DERIVATIVE: "a state derivative", STATE: "a continuous state", OUTPUT: f"{kind} output",
             INPUT: f"{kind} input"}
    what = " and ".join(names[role] for role in names if role in roles)
    return what or f"{kind} {v.causality.name}"


def _seeded(values: list, seeds: dict) -> list:
    """``values`` with a dual for each entry that ``seeds`` (index -> seed) gives a nonzero seed."""
    if not seeds:
        return values
    values = list(values)
    for index, seed in seeds.items():
        if seed:
            values[index] = Dual(values[index], seed)
    return values


def _check_count(seed: list, references: list, what: str) -> None:
    """ValueError unless ``seed`` has one entry per reference."""
    if len(seed) != len(references):
        entries = "entry" if len(seed) == 1 else "entries"
        raise ValueError(
            f"the seed has {len(seed)} {entries} for {len(references)} {what}; allowed: one per {what[:-1]}")
