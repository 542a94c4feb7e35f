"""The three loaded FMUs wired from ``registry.CONNECTIONS`` and recorded: what every master shares."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import CosimulationError
from ..registry import CONNECTIONS, CONTROLLER, ORDER, PLANT, REFERENCE
from . import signals
from .instance import LoadedFmu, LogMessage, type_name

__all__: list[str] = []  # the package's own: Feed, Wiring, Recorder, RunResult


def _check(values, names, at: float, bound: float) -> None:
    """At the first value that is not finite or beyond ``bound`` in magnitude, a CosimulationError naming it."""
    for name, value in zip(names, values):
        if not -bound <= value <= bound:
            reason = "is not finite" if not math.isfinite(value) else f"exceeds the bound {bound:g}"
            raise CosimulationError(f"diverged at t = {at:.6g} s: {name} = {value:.6g} {reason}", at, name, value)


class Feed:
    """The Real inputs of the FMU ``end`` and the outputs of the same names that feed them: ``sources``, each
    FMU with its outputs, in the order of ``registry.CONNECTIONS``."""

    def __init__(self, end: LoadedFmu, sources: list[tuple[LoadedFmu, list[str]]]):
        self.end = end
        self.inputs = [name for _, names in sources for name in names]
        self.refs = end.refs(self.inputs)
        self.sources = [(fmu.get_floats, fmu.refs(names)) for fmu, names in sources]
        self.names = [f"{fmu.name}.{name}" for fmu, names in sources for name in names]
        self.held: list[float] | None = None

    def read(self, at: float, bound: float | None) -> list[float]:
        """The feeding outputs now, checked against ``bound`` (None: not checked)."""
        values = [value for get, refs in self.sources for value in get(refs)]
        if bound is not None:
            _check(values, self.names, at, bound)
        return values

    def set(self, values: list[float]) -> None:
        """Set the inputs (noted in ``held``)."""
        self.end.set_floats(self.refs, values)
        self.held = values


class Wiring:
    """The three loaded FMUs (by name) by role, each FMU's ``Feed`` and the value references of the recorded
    outputs, looked up once per load: a wrong FMU file (a variable missing) is a CosimulationError here."""

    def __init__(self, fmus: dict[str, LoadedFmu]):
        for fmu in fmus.values():  # each FMU has the outputs recorded from it: a wrong file fails here
            fmu.refs(signals.RECORDED[fmu.name])
        self.fmus = fmus
        self.reference, self.plant, self.controller = fmus[REFERENCE], fmus[PLANT], fmus[CONTROLLER]
        sources: dict[str, dict[str, list[str]]] = {}
        for c in CONNECTIONS:
            sources.setdefault(c.end, {}).setdefault(c.start, []).append(c.signal)
        self.feeds = {end: Feed(fmus[end], [(fmus[start], names) for start, names in by_start.items()])
                      for end, by_start in sources.items()}
        self.measurements, self.voltages = self.feeds[CONTROLLER], self.feeds[PLANT]
        self.columns = ["time", *(name for names in signals.RECORDED.values() for name in names)]
        self.readers, offset = [], 1  # (FMU, kind, value references, table columns) of every recorded output
        for name, names in signals.RECORDED.items():
            fmu = fmus[name]
            for kind in ("Real", "Integer"):
                chosen = [i for i, output in enumerate(names) if type_name(fmu.variable(output)) == kind]
                self.readers.append((fmu, kind, fmu.refs([names[i] for i in chosen]), [offset + i for i in chosen]))
            offset += len(names)

    def in_order(self) -> list[LoadedFmu]:
        return [self.fmus[name] for name in ORDER]

    def exchange(self, at: float, bound: float | None, measured: list[float] | None = None) -> list[float]:
        """Outputs to inputs in dependency order: the measurements (read now unless given) to the controller,
        then its ``u`` (checked against ``bound``) to the plant, which is returned."""
        if measured is None:
            measured = self.measurements.read(at, bound)
        self.measurements.set(measured)
        u = self.voltages.read(at, bound)
        self.voltages.set(u)
        return u


class Recorder:
    """The rows of one run: ``time`` and every output of ``signals.RECORDED``, read at each ``record``
    (``rows`` allocated, more as needed)."""

    def __init__(self, wiring: Wiring, rows: int):
        self.columns = wiring.columns
        self.table = np.full((max(rows, 1), len(self.columns)), np.nan)
        self.rows = 0
        self.readers = [((fmu.get_floats if kind == "Real" else fmu.get_integers), refs, cols)
                        for fmu, kind, refs, cols in wiring.readers if refs]

    def record(self, at: float) -> None:
        """Read a row: every recorded output now, stamped with ``at`` (s)."""
        if self.rows == len(self.table):
            self.table = np.concatenate([self.table, np.full_like(self.table, np.nan)])
        table, row = self.table, self.rows
        table[row, 0] = at
        for get, refs, cols in self.readers:
            table[row, cols] = get(refs)
        self.rows = row + 1

    @property
    def last_time(self) -> float:
        """The time in s of the last row recorded."""
        return float(self.table[self.rows - 1, 0])

    def result(self) -> np.ndarray:
        """The rows recorded so far with the tracking errors, dtype ``signals.DTYPE``."""
        result = np.zeros(self.rows, dtype=signals.DTYPE)
        for index, name in enumerate(self.columns):
            result[name] = self.table[: self.rows, index]
        signals.add_tracking_errors(result)
        return result


@dataclass(kw_only=True)
class RunResult:
    """What every finished run holds: its rows (``Recorder.result``), wall time (s), settings, the FMUs' log,
    their ``path`` and ``build_id`` by name, and where a watch stopped it (s; None: at its stop time)."""

    result: np.ndarray
    wall_time: float
    settings: dict
    log: list[LogMessage] = field(default_factory=list)
    fmus: dict = field(default_factory=dict)
    stopped_at: float | None = None
