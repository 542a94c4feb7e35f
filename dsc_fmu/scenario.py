"""Scenarios: TOML files read into a validated, typed ``Scenario`` with every FMU parameter set."""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .errors import DscFmuError
from .models.parameters import INPUT_COUPLINGS
from .models.reference import min_speed
from .registry import CONTROLLER, FMUS, PLANT, REFERENCE

__all__ = [
    "ScenarioError", "Simulation", "Scenario", "ORDERS", "COUPLINGS", "STABILITIES", "INTERFACES", "REFERENCES",
    "load_scenario",
    "scenario_names", "SCENARIO_DIR",
]

ORDERS = ("gauss-seidel", "jacobi")
COUPLINGS = ("hold", "linear")
"""How the exchanged signals vary over a step: held (zero-order hold), or linear (first-order: the plant
extrapolates u, the controller interpolates its inputs with Gauss-Seidel and extrapolates them with
Jacobi). It sets the FMUs' ``coupling`` parameters, which a scenario does not set itself."""
STABILITIES = ("settled", "local")
"""What a step-size study calls a stable run (``study.rows.stability_definition``): "settled" judges where
the run ends up; "local", for a scenario that starts in steady tracking, also asks that the run stay
with the reference solution from its start (the stability of steady tracking, what the linearised
prediction predicts)."""
INTERFACES = ("co-simulation", "model-exchange")
"""How the FMUs run: stepped by the co-simulation master, or integrated as one ODE through model exchange."""
REFERENCES = ("monolithic", "model-exchange")
"""What a step-size study measures its runs against: the monolithic ODE of the equations
(``cosim.reference_solution``), or the three FMUs as one ODE through model exchange
(``cosim.model_exchange``), both solved with DOP853 at a relative tolerance of 1e-10."""

_HERE = Path(__file__).parent
SCENARIO_DIR = next((d for d in (_HERE / "scenarios", _HERE.parent / "scenarios") if d.is_dir()), _HERE / "scenarios")

FMU_OF_TABLE = {"plant": PLANT, "controller": CONTROLLER, "reference": REFERENCE}
TABLES = {table: tuple(v for v in FMUS[name].parameters if v.name != "coupling") for table, name in FMU_OF_TABLE.items()}


class ScenarioError(DscFmuError, ValueError):
    """A scenario (file, key or value) that cannot be run; the message names what and what is allowed."""


@dataclass(frozen=True)
class Simulation:
    """How the scenario is co-simulated: stop time (s), communication step (s), coupling order
    (``ORDERS``), coupling (``COUPLINGS``), output interval (s), the bound on |signal| beyond
    which a run counts as diverged, and for an error-controlled step its ``tolerance`` (m: the
    estimated position error of each step; None: a fixed step) within ``[h_min, h_max]`` (s),
    starting from ``step_size``, with the position error per volt of coupling defect ``error_gain``
    (m/V, see ``cosim.step_control``). ``input_derivatives`` realises the linear coupling through the
    standard route instead of the FMUs' ``coupling`` parameters (``cosim.derivatives``: the master sets
    the slopes with ``fmi2SetRealInputDerivatives``, the FMUs hold; FMI 2.0 FMUs, a fixed step).
    ``stability`` (``STABILITIES``) is how a step-size study judges a run, ``reference`` (``REFERENCES``)
    what it measures the runs' deviations against."""

    stop_time: float = 30.0
    step_size: float = 1e-3
    order: str = "gauss-seidel"
    output_interval: float = 0.01
    bound: float = 1e6
    coupling: str = "hold"
    tolerance: float | None = None
    h_min: float = 1e-5
    h_max: float = 0.02
    error_gain: float = 0.02
    input_derivatives: bool = False
    stability: str = "settled"
    reference: str = "monolithic"

    def check(self, where: str) -> None:
        """Raise ScenarioError naming ``where`` if a setting is out of its range."""
        positive = ("stop_time", "step_size", "output_interval", "bound", "h_min", "h_max", "error_gain")
        for key in (*positive, *(("tolerance",) if self.tolerance is not None else ())):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ScenarioError(f"{where}: [simulation] {key} = {value!r} is not a number; allowed: > 0")
            if not (math.isfinite(value) and value > 0):
                raise ScenarioError(f"{where}: [simulation] {key} = {value!r} is not allowed; allowed: > 0")
        if self.h_min > self.h_max:
            raise ScenarioError(f"{where}: [simulation] h_min = {self.h_min!r} is not allowed; allowed: <= h_max = {self.h_max!r}")
        for key, allowed in (("order", ORDERS), ("coupling", COUPLINGS), ("stability", STABILITIES),
                             ("reference", REFERENCES)):
            if getattr(self, key) not in allowed:
                raise ScenarioError(
                    f"{where}: [simulation] {key} = {getattr(self, key)!r} is not allowed; allowed: {', '.join(allowed)}"
                )
        if not isinstance(self.input_derivatives, bool):
            raise ScenarioError(f"{where}: [simulation] input_derivatives = {self.input_derivatives!r} is not "
                                "allowed; allowed: true, false")
        if self.input_derivatives and (self.coupling != "linear" or self.tolerance is not None):
            here = f"coupling = {json.dumps(self.coupling)}" + (
                "" if self.tolerance is None else f", tolerance = {self.tolerance!r}")
            raise ScenarioError(f"{where}: [simulation] input_derivatives = true realises the linear coupling at a "
                                f"fixed step; allowed: with coupling = \"linear\" and no tolerance (here {here})")

    def fmu_coupling(self, fmu: str) -> int | None:
        """The ``coupling`` parameter of FMU ``fmu`` for these settings (None: it has none)."""
        if fmu == REFERENCE:
            return None
        if self.coupling == "hold":
            return INPUT_COUPLINGS.index("hold")
        ends = fmu == CONTROLLER and self.order == "gauss-seidel"  # its inputs set for the step's end
        return INPUT_COUPLINGS.index("interpolate" if ends else "extrapolate")


@dataclass(frozen=True)
class Scenario:
    """A validated scenario: settings and the value of every parameter of the three FMUs."""

    name: str
    description: str
    source: str
    simulation: Simulation
    plant: dict
    controller: dict
    reference: dict

    def parameters(self, fmu: str, *, slopes_from_master: bool = False) -> dict:
        """Parameter values of the FMU named ``fmu`` (``MobileRobot``, ``DSCController``, ``ReferenceRobot``):
        its table, and its ``coupling`` from the simulation settings, or the hold where the master gives
        the slopes (``slopes_from_master``: ``input_derivatives``, which only this project's master does)."""
        table = {v: k for k, v in FMU_OF_TABLE.items()}[fmu]
        coupling = self.simulation.fmu_coupling(fmu)
        if coupling is None:
            return getattr(self, table)
        return {**getattr(self, table), "coupling": INPUT_COUPLINGS.index("hold") if slopes_from_master else coupling}

    def with_simulation(self, **settings) -> Scenario:
        """This scenario with some simulation settings replaced (None leaves a setting as it is), all of
        them checked."""
        changed = {k: v for k, v in settings.items() if v is not None}
        unknown = set(changed) - {f.name for f in dataclasses.fields(Simulation)}
        if unknown:
            raise ScenarioError(f"{self.source}: unknown simulation setting {sorted(unknown)[0]}")
        simulation = dataclasses.replace(self.simulation, **changed)
        simulation.check(self.source)
        scenario = dataclasses.replace(self, simulation=simulation)
        _check_reference_speed(scenario)
        return scenario


def scenario_names() -> list[str]:
    """Names of the scenarios shipped in ``scenarios/``."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def _resolve(name_or_path: str | Path) -> Path:
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise ScenarioError(f"{path}: scenario file not found")
        return path
    candidate = SCENARIO_DIR / f"{name_or_path}.toml"
    if not candidate.is_file():
        raise ScenarioError(
            f"unknown scenario {str(name_or_path)!r}; allowed: a path to a TOML file or one of "
            f"{', '.join(scenario_names())}"
        )
    return candidate


def _table(data: dict, key: str, where: str) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise ScenarioError(f"{where}: {key} must be a table [{key}]")
    return value


def _parameters(table_name: str, given: dict, where: str) -> dict:
    variables = {v.name: v for v in TABLES[table_name]}
    values = {name: v.start for name, v in variables.items()}
    for key, value in given.items():
        v = variables.get(key)
        if v is None and key == "coupling":
            raise ScenarioError(f"{where}: [{table_name}] coupling is not set here; allowed: [simulation] coupling = "
                                f"{' or '.join(repr(c) for c in COUPLINGS)}, which sets it in every FMU")
        if v is None:
            raise ScenarioError(
                f"{where}: unknown key [{table_name}] {key}; allowed: {', '.join(variables)}"
            )
        if v.choices:
            if value not in v.choices:
                raise ScenarioError(
                    f"{where}: [{table_name}] {key} = {value!r} is not allowed; allowed: {', '.join(v.choices)}"
                )
            values[key] = v.choices.index(value)
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ScenarioError(f"{where}: [{table_name}] {key} = {value!r} is not a number; allowed: {v.allowed}")
        reason = v.check(value)
        if reason:
            raise ScenarioError(f"{where}: [{table_name}] {reason}; allowed: {v.allowed}")
        values[key] = float(value)
    return values


def _check_reference_speed(scenario: Scenario) -> None:
    """Assumption 2: vr > 0 over the whole run, else a usage error (docs/model.md §2)."""
    lowest = min_speed(scenario.reference, scenario.simulation.stop_time)
    if not lowest > 0:
        raise ScenarioError(
            f"{scenario.source}: [reference] v_r reaches {lowest:g} m/s during the run; "
            "allowed: v_r > 0 at all times (Assumption 2)"
        )


def load_scenario(name_or_path: str | Path = "paper") -> Scenario:
    """Read and validate a scenario given by name (from ``scenarios/``) or by path to a TOML file."""
    path = _resolve(name_or_path)
    where = str(path)
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as error:
        raise ScenarioError(f"{where}: cannot read: {error}") from None
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{where}: not valid TOML: {error}") from None
    allowed = {"name", "description", "simulation", *TABLES}
    for key in data:
        if key not in allowed:
            raise ScenarioError(f"{where}: unknown key {key}; allowed: {', '.join(sorted(allowed))}")
    settings = _table(data, "simulation", where)
    fields = {f.name for f in dataclasses.fields(Simulation)}
    for key in settings:
        if key not in fields:
            raise ScenarioError(f"{where}: unknown key [simulation] {key}; allowed: {', '.join(sorted(fields))}")
    simulation = Simulation(**settings)
    simulation.check(where)
    for key in ("name", "description"):
        if not isinstance(data.get(key, ""), str):
            raise ScenarioError(f"{where}: {key} = {data[key]!r} must be a string")
    scenario = Scenario(
        name=data.get("name", path.stem),
        description=data.get("description", ""),
        source=where,
        simulation=simulation,
        **{name: _parameters(name, _table(data, name, where), where) for name in TABLES},
    )
    _check_reference_speed(scenario)
    return scenario
