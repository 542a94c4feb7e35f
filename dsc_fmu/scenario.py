"""Scenarios: TOML files read into a validated, typed ``Scenario`` with every FMU parameter set."""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .errors import DscFmuError
from .models.adaptation import projection_conflict
from .models.parameters import INPUT_COUPLINGS
from .models.reference import min_speed
from .registry import CONTROLLER, FMUS, PLANT, REFERENCE

__all__ = [
    "ScenarioError", "Simulation", "Scenario", "Order", "Coupling", "Stability", "Interface", "Reference", "ORDERS", "COUPLINGS",
    "STABILITIES", "INTERFACES", "REFERENCES", "Method", "METHODS", "load_scenario", "SCENARIO_DIR",
]


class _Named(enum.StrEnum):
    """A closed set of names: a member is ``NAME = "name", *attributes``, kept by its ``__init__``."""

    def __new__(cls, value: str, *attributes):
        member = str.__new__(cls, value)
        member._value_ = value
        return member


class Order(_Named):
    """In what order the FMUs step and exchange within a communication step.

    ``"gauss-seidel"`` (``sequential``): the reference and the plant step, the controller's inputs are
    set from their new outputs, then the controller steps. ``"jacobi"``: all three step from the values
    of the step's start, and exchange at its end.
    """

    GAUSS_SEIDEL = "gauss-seidel", True
    JACOBI = "jacobi", False

    def __init__(self, value: str, sequential: bool):
        self.sequential = sequential


class Coupling(_Named):
    """How the exchanged signals vary over a communication step (docs/co-simulation.md).

    ``"hold"``: held over the step (zero-order hold). ``"linear"``: on a line (first-order hold): the
    plant extrapolates ``u``, the controller interpolates its inputs with Gauss-Seidel and extrapolates
    them with Jacobi. It sets the FMUs' ``coupling`` parameters: ``from_start`` and ``to_end`` are the
    input laws (``models.parameters.INPUT_COUPLINGS``) for inputs set at a step's start and at its end
    (the controller's, with Gauss-Seidel); ``order`` is the order in h of the deviation it causes and of
    its defect (``cosim.step_control``).
    """

    HOLD = "hold", 1, "hold", "hold"
    LINEAR = "linear", 2, "extrapolate", "interpolate"

    def __init__(self, value: str, order: int, from_start: str, to_end: str):
        self.order, self.from_start, self.to_end = order, from_start, to_end


class Interface(_Named):
    """How the FMUs run: stepped by the co-simulation master, or integrated as one ODE through model exchange.

    ``settings``: the ``Simulation`` settings a run through this interface reads.
    """

    CO_SIMULATION = "co-simulation", ("stop_time", "step_size", "order", "output_interval", "bound", "coupling",
                                      "tolerance", "h_min", "h_max", "error_gain", "input_derivatives")
    MODEL_EXCHANGE = "model-exchange", ("tolerance", "method", "stop_time", "output_interval", "bound")

    def __init__(self, value: str, settings: tuple):
        self.settings = settings


class Stability(_Named):
    """What a step-size study calls a stable run (``study.rows.stability_definition``).

    ``"settled"`` judges where the run ends up; ``"local"`` (``from_start``), for a scenario that starts
    in steady tracking, also asks that the run stay with the reference solution from its start (the
    stability of steady tracking, what the linearised prediction predicts).
    """

    SETTLED = "settled", False
    LOCAL = "local", True

    def __init__(self, value: str, from_start: bool):
        self.from_start = from_start


class Reference(_Named):
    """What a step-size study measures its runs against, solved with DOP853 at a relative tolerance of 1e-10.

    ``"monolithic"``: the monolithic ODE of the equations (``cosim.reference_solution``);
    ``"model-exchange"`` (``through_fmus``, so depending on their builds): the three FMUs as one ODE
    through model exchange (``cosim.model_exchange``).
    """

    MONOLITHIC = "monolithic", False
    MODEL_EXCHANGE = "model-exchange", True

    def __init__(self, value: str, through_fmus: bool):
        self.through_fmus = through_fmus


class Method(_Named):
    """SciPy's integrator of a model-exchange run (``cosim.model_exchange``).

    ``"DOP853"``: the explicit Runge-Kutta of order 8; ``"Radau"`` and ``"BDF"`` (``implicit``): given
    the loop's Jacobian from the FMUs' directional derivatives.
    """

    DOP853 = "DOP853", False
    RADAU = "Radau", True
    BDF = "BDF", True

    def __init__(self, value: str, implicit: bool):
        self.implicit = implicit


# The names of each closed set's members, as scenarios and the command line give them.
ORDERS, COUPLINGS, STABILITIES, INTERFACES, REFERENCES, METHODS = (
    tuple(member.value for member in kind) for kind in (Order, Coupling, Stability, Interface, Reference, Method))

_HERE = Path(__file__).parent
SCENARIO_DIR = next((d for d in (_HERE / "scenarios", _HERE.parent / "scenarios") if d.is_dir()), _HERE / "scenarios")

FMU_OF_TABLE = {"plant": PLANT, "controller": CONTROLLER, "reference": REFERENCE}
TABLES = {table: tuple(v for v in FMUS[name].parameters if v.name != "coupling") for table, name in FMU_OF_TABLE.items()}


class ScenarioError(DscFmuError, ValueError):
    """A scenario (file, key or value) that cannot be run; the message names what and what is allowed."""


def one_of(allowed, value, name: str):
    """The member of the closed set ``allowed`` (``Order``, ``Coupling``, ...) named ``value``, or for a sequence of
    names ``value`` itself; otherwise ScenarioError
    ``"{name} = {value!r} is not allowed; allowed: {the names, comma-separated}"``.

    >>> one_of(Order, "jacobi", "order") is Order.JACOBI
    True
    >>> one_of(("rk4", "euler"), "tustin", "discretization")
    Traceback (most recent call last):
    ...
    dsc_fmu.scenario.ScenarioError: discretization = 'tustin' is not allowed; allowed: rk4, euler
    """
    names = tuple(allowed)
    if not (isinstance(value, str) and value in names):
        raise ScenarioError(f"{name} = {value!r} is not allowed; allowed: {', '.join(names)}")
    return allowed(value) if isinstance(allowed, enum.EnumType) else value


_CLOSED_SETS = {"order": Order, "coupling": Coupling, "stability": Stability, "reference": Reference,
                "method": Method}


@dataclass(frozen=True)
class Simulation:
    """How a scenario is simulated: the ``[simulation]`` table of a scenario file.

    Names of closed sets become their members (``Order``, ``Coupling``, ...); ``check`` checks the ranges.

    Parameters
    ----------
    stop_time : float, optional
        s. Default 30.
    step_size : float, optional
        Communication step in s (the first one of an error-controlled run). Default 1e-3.
    order : Order or {"gauss-seidel", "jacobi"}, optional
        Coupling order. Default "gauss-seidel".
    output_interval : float, optional
        Recording interval in s. Default 0.01.
    bound : float, optional
        A run whose measurements or voltages exceed it in magnitude (SI units) diverged. Default 1e6.
    coupling : Coupling or {"hold", "linear"}, optional
        How the exchanged signals vary over a step. Default "hold".
    tolerance : float, optional
        Error-controlled step: the estimated position error (m) each step may add. Default None: fixed.
    h_min, h_max : float, optional
        Range of the error-controlled step in s. Defaults 1e-5 and 0.02.
    error_gain : float, optional
        Position error per volt of coupling defect in m/V (``cosim.step_control``). Default 0.02.
    input_derivatives : bool, optional
        Realise the linear coupling by ``fmi2SetRealInputDerivatives`` (``cosim.derivatives``; FMI 2.0,
        a fixed step) instead of the FMUs' ``coupling`` parameters. Default False.
    stability : Stability or {"settled", "local"}, optional
        How a step-size study judges a run. Default "settled".
    reference : Reference or {"monolithic", "model-exchange"}, optional
        What a step-size study measures the runs' deviations against. Default "monolithic".
    method : Method or {"DOP853", "Radau", "BDF"}, optional
        The integrator of a model-exchange run. Default "DOP853".
    """

    stop_time: float = 30.0
    step_size: float = 1e-3
    order: Order = Order.GAUSS_SEIDEL
    output_interval: float = 0.01
    bound: float = 1e6
    coupling: Coupling = Coupling.HOLD
    tolerance: float | None = None
    h_min: float = 1e-5
    h_max: float = 0.02
    error_gain: float = 0.02
    input_derivatives: bool = False
    stability: Stability = Stability.SETTLED
    reference: Reference = Reference.MONOLITHIC
    method: Method = Method.DOP853

    def __post_init__(self):
        # Names become their types; a name that is none stays as given, for ``check`` to name.
        for key, kind in _CLOSED_SETS.items():
            try:
                object.__setattr__(self, key, kind(getattr(self, key)))
            except ValueError:
                pass

    def check(self, where: str) -> None:
        """Check every setting against its range.

        Parameters
        ----------
        where : str
            Where the settings come from (a file), for the message.

        Raises
        ------
        ScenarioError
            Naming ``where``, the first setting out of its range and what is allowed.
        """
        positive = ("stop_time", "step_size", "output_interval", "bound", "h_min", "h_max", "error_gain")
        for key in (*positive, *(("tolerance",) if self.tolerance is not None else ())):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ScenarioError(f"{where}: [simulation] {key} = {value!r} is not a number; allowed: > 0")
            if not (math.isfinite(value) and value > 0):
                raise ScenarioError(f"{where}: [simulation] {key} = {value!r} is not allowed; allowed: > 0")
        if self.h_min > self.h_max:
            raise ScenarioError(f"{where}: [simulation] h_min = {self.h_min!r} is not allowed; allowed: <= h_max = {self.h_max!r}")
        for key, kind in _CLOSED_SETS.items():
            one_of(kind, getattr(self, key), f"{where}: [simulation] {key}")
        if not isinstance(self.input_derivatives, bool):
            raise ScenarioError(f"{where}: [simulation] input_derivatives = {self.input_derivatives!r} is not "
                                "allowed; allowed: true, false")
        if self.input_derivatives and (self.coupling is not Coupling.LINEAR or self.tolerance is not None):
            here = f"coupling = {json.dumps(self.coupling)}" + (
                "" if self.tolerance is None else f", tolerance = {self.tolerance!r}")
            raise ScenarioError(f"{where}: [simulation] input_derivatives = true realises the linear coupling at a "
                                f"fixed step; allowed: with coupling = \"linear\" and no tolerance (here {here})")

    def fmu_coupling(self, fmu: str) -> int | None:
        """The ``coupling`` parameter of an FMU for these settings.

        Parameters
        ----------
        fmu : str
            The FMU's name (``registry.PLANT``, ``registry.CONTROLLER``, ``registry.REFERENCE``).

        Returns
        -------
        int or None
            The index in ``models.parameters.INPUT_COUPLINGS`` of its input law (``Coupling``); None for
            an FMU without inputs.
        """
        if fmu == REFERENCE:
            return None
        ends = fmu == CONTROLLER and self.order.sequential  # its inputs set for the step's end
        return INPUT_COUPLINGS.index(self.coupling.to_end if ends else self.coupling.from_start)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario (``load_scenario``, ``with_simulation``): settings and every FMU parameter's value.

    Parameters
    ----------
    name : str
        The scenario's name.
    description : str
        One line on what it shows.
    source : str
        The file it was read from, named in error messages.
    simulation : Simulation
        How it is simulated.
    plant, controller, reference : dict
        Every parameter of the MobileRobot, DSCController and ReferenceRobot FMUs by name (SI units as
        in docs/model.md; choices as their index), except ``coupling``, which ``simulation`` sets.
    """

    name: str
    description: str
    source: str
    simulation: Simulation
    plant: dict
    controller: dict
    reference: dict

    def parameters(self, fmu: str, *, slopes_from_master: bool = False) -> dict:
        """Parameter values of one FMU.

        Parameters
        ----------
        fmu : str
            The FMU's name (``MobileRobot``, ``DSCController``, ``ReferenceRobot``).
        slopes_from_master : bool, optional
            The master gives the slopes (``input_derivatives``): the FMU holds. Default False.

        Returns
        -------
        dict
            Its table, and its ``coupling`` (``Simulation.fmu_coupling``).
        """
        table = {v: k for k, v in FMU_OF_TABLE.items()}[fmu]
        coupling = self.simulation.fmu_coupling(fmu)
        if coupling is None:
            return getattr(self, table)
        return {**getattr(self, table), "coupling": INPUT_COUPLINGS.index("hold") if slopes_from_master else coupling}

    def with_simulation(self, **settings) -> Scenario:
        """This scenario with some simulation settings replaced, all of them checked.

        Parameters
        ----------
        **settings
            ``Simulation`` fields by name; None leaves a setting as it is.

        Returns
        -------
        Scenario
            The new scenario; this one if nothing is replaced.

        Raises
        ------
        ScenarioError
            For an unknown setting, one out of its range, or a reference speed not positive over the run.
        """
        changed = {k: v for k, v in settings.items() if v is not None}
        if not changed:  # checked already, where it entered (``load_scenario`` or an earlier replacement)
            return self
        unknown = set(changed) - {f.name for f in dataclasses.fields(Simulation)}
        if unknown:
            raise ScenarioError(f"{self.source}: unknown simulation setting {sorted(unknown)[0]}")
        simulation = dataclasses.replace(self.simulation, **changed)
        simulation.check(self.source)
        scenario = dataclasses.replace(self, simulation=simulation)
        _check_reference_speed(scenario)
        return scenario


def scenario_names() -> list[str]:
    """The sorted names of the scenarios shipped in ``scenarios/``."""
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
            values[key] = v.choices.index(one_of(v.choices, value, f"{where}: [{table_name}] {key}"))
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
    """Read and validate a scenario.

    Parameters
    ----------
    name_or_path : str or pathlib.Path, optional
        A scenario's name (from ``scenarios/``, ``scenario_names``) or the path of a TOML file.
        Default "paper".

    Returns
    -------
    Scenario
        Every FMU parameter set: the file's values, the others at their defaults.

    Raises
    ------
    ScenarioError
        For a file missing or not TOML, an unknown key, a value out of its range, a reference speed
        not positive over the run (Assumption 2), or a projection's set that is empty or leaves out an
        initial estimate.
    """
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
    conflict = projection_conflict(scenario.controller)
    if conflict is not None:
        raise ScenarioError(f"{where}: [controller] {conflict}")
    return scenario
