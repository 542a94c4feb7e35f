"""Step-size sensitivity sweeps: the cases (step, order, discretisation, parameter values, samples) and their grid.

A sweep runs one co-simulation per ``Case``; a ``Grid`` says what it varies and ``build_cases`` makes
the full grid from it (the options of ``dsc-fmu sweep``: ``parse_set``, ``parse_perturb``), ``apply``
turns a case into the scenario it runs. A ``Runner`` says where the runs go (local processes or a Dask
scheduler, checked with ``parse_scheduler`` and ``check_scheduler``). Running them (cached, on a
process pool or a Dask cluster) is ``dsc_fmu.study.execute.Workers``.

>>> parse_set("controller.k4=0.5,1,2")
('controller.k4', (0.5, 1.0, 2.0))
>>> str(parse_perturb("plant.mc=20%")), str(parse_perturb("plant.mc=25:35"))
('plant.mc=20%', 'plant.mc=25:35')
>>> default_step_sizes()[:5], default_step_sizes()[-1]
([0.0001, 0.000178, 0.000316, 0.000562, 0.001], 0.05)
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import socket
from dataclasses import dataclass

import numpy as np

from ..models.parameters import DISCRETIZATIONS, Variable
from ..errors import DscFmuError
from ..scenario import COUPLINGS, ORDERS, TABLES, Coupling, Order, Scenario, ScenarioError, one_of

__all__ = ["Case", "SweepError", "apply", "Grid", "Runner", "SCHEDULER_TIMEOUT", "DEFAULT_TOLERANCES"]

SCHEDULER_TIMEOUT = 10.0  # s: how long a sweep waits for its Dask scheduler to answer
DEFAULT_TOLERANCES = (1e-2, 1e-3, 1e-4)  # m: the error-controlled runs of a sweep
_OWN_OPTION = {"controller.discretization": "the sweep's discretizations option (rk4, euler)"}


class SweepError(DscFmuError, RuntimeError):
    """A sweep that cannot run as asked (for example an unreachable Dask scheduler); one-line message."""


def _number(value):
    """A parameter value as stored in a case: a choice's name stays a string, a number becomes a float."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ScenarioError(f"{value!r} is not a number or a choice name")
    return float(value)


@dataclass(frozen=True)
class Case:
    """One run of a sweep. Numbers are stored as floats, an order and a coupling as their types.

    Parameters
    ----------
    step_size : float
        Communication step in s; the first one if error-controlled.
    order : Order or {"gauss-seidel", "jacobi"}, optional
        Coupling order. Default "gauss-seidel".
    discretization : {"rk4", "euler"}, optional
        Controller discretisation (``DISCRETIZATIONS``). Default "rk4".
    overrides : tuple, optional
        Parameter overrides as ``("table.name", value)`` pairs, a choice by its name. Default none.
    sample : int or None, optional
        The Monte Carlo sample index; None (the default) without perturbations.
    coupling : Coupling or {"hold", "linear"}, optional
        How inputs are extrapolated over a step. Default "hold".
    tolerance : float or None, optional
        Tolerance of an error-controlled step in m; None (the default): a fixed step.

    Raises
    ------
    ScenarioError
        One line naming what is allowed, if the order, the discretisation or the coupling is not.
    """

    step_size: float
    order: Order = Order.GAUSS_SEIDEL
    discretization: str = "rk4"
    overrides: tuple = ()
    sample: int | None = None
    coupling: Coupling = Coupling.HOLD
    tolerance: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "step_size", float(self.step_size))
        object.__setattr__(self, "order", one_of(Order, self.order, "order"))
        object.__setattr__(self, "discretization", one_of(DISCRETIZATIONS, self.discretization, "discretization"))
        object.__setattr__(self, "coupling", one_of(Coupling, self.coupling, "coupling"))
        if self.tolerance is not None:
            object.__setattr__(self, "tolerance", float(self.tolerance))
        object.__setattr__(self, "overrides", tuple((str(k), _number(v)) for k, v in self.overrides))
        if self.sample is not None:
            object.__setattr__(self, "sample", int(self.sample))

    @property
    def label(self) -> str:
        """A short description for messages, e.g. ``h = 0.001 s, jacobi, euler, hold coupling, controller.k4 = 0.5``."""
        parts = [f"h = {self.step_size:g} s" if self.tolerance is None else f"tolerance = {self.tolerance:g} m",
                 self.order, self.discretization, f"{self.coupling} coupling"]
        parts += [f"{key} = {value:g}" if isinstance(value, float) else f"{key} = {value}"
                  for key, value in self.overrides]
        return ", ".join(parts + ([] if self.sample is None else [f"sample {self.sample}"]))


@dataclass(frozen=True)
class Perturbation:
    """A plant parameter ``plant.NAME`` drawn uniformly per Monte Carlo sample: within the fraction
    ``relative`` of its nominal value (0.2 for 20 %), or else in ``[low, high]`` (the parameter's unit)."""

    key: str
    relative: float | None = None
    low: float | None = None
    high: float | None = None

    def bounds(self, nominal: float) -> tuple[float, float]:
        """``(low, high)``, the range drawn from, around the parameter's ``nominal`` value."""
        if self.relative is None:
            return self.low, self.high
        return nominal * (1.0 - self.relative), nominal * (1.0 + self.relative)

    def __str__(self) -> str:
        if self.relative is None:
            return f"{self.key}={self.low:g}:{self.high:g}"
        return f"{self.key}={100.0 * self.relative:g}%"


def _variable(key: str, option: str) -> Variable:
    """The Variable named by ``key`` (``table.name``), else ScenarioError listing what is allowed."""
    table, _, name = key.partition(".")
    if table == "simulation":
        raise ScenarioError(f"{option} {key}: simulation settings are not swept this way; the step size and the "
                            "coupling order have their own options, the rest comes from the scenario file")
    if table not in TABLES or not name:
        raise ScenarioError(f"{option} {key}: unknown parameter; allowed: TABLE.NAME with TABLE one of "
                            f"{', '.join(TABLES)} (for example controller.k4)")
    variables = {v.name: v for v in TABLES[table]}
    if name not in variables:
        raise ScenarioError(f"{option} {key}: unknown parameter; allowed: "
                            f"{', '.join(f'{table}.{n}' for n in variables)}")
    if key in _OWN_OPTION:
        raise ScenarioError(f"{option} {key}: not allowed here; it is swept with {_OWN_OPTION[key]}")
    return variables[name]


def _value(key: str, variable: Variable, value, option: str):
    """``value`` (text or number) checked for ``variable``: a choice's name, or a float in range."""
    if variable.choices:
        return one_of(variable.choices, value, f"{option} {key}")
    try:
        number = float(value) if isinstance(value, str) else _number(value)
    except (ValueError, ScenarioError):
        raise ScenarioError(f"{option} {key} = {value!r} is not a number; allowed: {variable.allowed}") from None
    reason = variable.check(number)
    if reason:
        raise ScenarioError(f"{option} {key}: {reason}; allowed: {variable.allowed}")
    return number


def parse_set(text: str) -> tuple[str, tuple]:
    """``(key, values)`` of ``--set table.name=v1,v2,...``: numbers in the parameter's range as floats, or
    a choice's names (``reference.profile=constant,figure_eight``), repeated ones kept once; else
    ScenarioError (one line)."""
    key, sep, raw = (part.strip() for part in text.partition("="))
    if not sep or not key or not raw:
        raise ScenarioError(f"--set {text!r}: expected TABLE.NAME=VALUE[,VALUE...], for example controller.k4=0.5,1,2")
    variable = _variable(key, "--set")
    values = [_value(key, variable, item.strip(), "--set") for item in raw.split(",")]
    return key, tuple(dict.fromkeys(values))


def parse_perturb(text: str) -> Perturbation:
    """The Perturbation of ``--perturb plant.name=P%`` or ``plant.name=LOW:HIGH``; else ScenarioError (one
    line). Only plant parameters: the paper's Assumption 1 (unknown but bounded parameters) concerns the plant."""
    key, sep, raw = (part.strip() for part in text.partition("="))
    if not sep or not key or not raw:
        raise ScenarioError(f"--perturb {text!r}: expected plant.NAME=P% or plant.NAME=LOW:HIGH, "
                            "for example plant.mc=20% or plant.mc=25:35")
    if key.partition(".")[0] in TABLES and key.partition(".")[0] != "plant":
        raise ScenarioError(f"--perturb {key}: only plant parameters can be perturbed (the paper's Assumption 1 "
                            "concerns the plant's parameters); allowed: plant.NAME, for example plant.mc")
    variable = _variable(key, "--perturb")
    if variable.name == "max_step":
        raise ScenarioError(f"--perturb {key}: max_step is a solver setting, not a physical parameter; "
                            "allowed: the other plant parameters")
    try:
        if raw.endswith("%"):
            relative = float(raw[:-1]) / 100.0
            if not (math.isfinite(relative) and relative > 0):
                raise ValueError
            return Perturbation(key, relative=relative)
        low, colon, high = raw.partition(":")
        low, high = float(low), float(high)
        if not colon or not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ValueError
    except ValueError:
        raise ScenarioError(f"--perturb {key}={raw}: not a bound; allowed: P% with P > 0 (e.g. 20%) "
                            "or LOW:HIGH with LOW < HIGH (e.g. 25:35)") from None
    perturbation = Perturbation(key, low=low, high=high)
    _check_range(perturbation, variable, low, high)
    return perturbation


def _check_range(perturbation: Perturbation, variable: Variable, low: float, high: float) -> None:
    """ScenarioError if the range ``[low, high]`` holds values the parameter does not allow."""
    for end in (low, high):
        reason = variable.check(end)
        if reason:
            raise ScenarioError(f"--perturb {perturbation}: the range [{low:g}, {high:g}] allows {reason}; "
                                f"allowed: {variable.allowed}")


def default_step_sizes(per_decade: int = 4, smallest: float = 1e-4, largest: float = 5e-2) -> list[float]:
    """Communication steps in s, ``per_decade`` log-spaced from ``smallest`` up to ``largest`` (both included),
    rounded to 3 significant digits, the decades on the grid: by default 1e-4, 1.78e-4, ..., 3.16e-2, 5e-2."""
    count = math.floor(per_decade * math.log10(largest / smallest) + 1e-9)
    steps = [float(f"{smallest * 10 ** (k / per_decade):.3g}") for k in range(count + 1)]
    return steps if steps[-1] == largest else [*steps, largest]


def _draw(scenario: Scenario, perturbations, samples, seed) -> list[tuple[int | None, tuple]]:
    """``(sample, ((key, value), ...))`` per Monte Carlo sample, drawn with ``default_rng(seed)``;
    ``[(None, ())]`` without perturbations."""
    if not perturbations:
        if samples not in (None, 0, 1):
            raise ScenarioError(f"samples = {samples!r} needs at least one perturbation (--perturb plant.NAME=P%)")
        return [(None, ())]
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise ScenarioError(f"--samples {samples} is not allowed with --perturb; allowed: a whole number >= 1")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ScenarioError(f"seed = {seed!r} is not allowed; allowed: a whole number >= 0")
    ranges = []
    for p in perturbations:
        variable = _variable(p.key, "--perturb")
        low, high = p.bounds(scenario.plant[variable.name])
        if not low < high:
            raise ScenarioError(f"--perturb {p}: the nominal value is {scenario.plant[variable.name]:g}, so the range "
                                "is empty; allowed: an absolute range LOW:HIGH")
        _check_range(p, variable, low, high)
        ranges.append((p.key, variable, low, high))
    rng = np.random.default_rng(seed)
    draws = []
    for sample in range(samples):
        values = []
        for key, variable, low, high in ranges:
            value = float(rng.uniform(low, high))
            if variable.check(value):  # cannot happen for a range checked at both ends; never run it unchecked
                raise ScenarioError(f"--perturb {key}: drew {value!r}: {variable.check(value)}")
            values.append((key, value))
        draws.append((sample, tuple(values)))
    return draws


def build_cases(scenario: Scenario, step_sizes=None, orders=None, discretizations=None, sets=(), perturbations=(),
                samples: int | None = None, seed: int = 0, couplings=None, tolerances=()) -> list[Case]:
    """The full grid of a sweep, every case checked up front.

    Every step size x order x discretisation x coupling x combination of the ``sets`` values x Monte
    Carlo sample, in that nesting (the step size outermost); then, for each of the ``tolerances``, an
    error-controlled run of every order x discretisation x combination x sample, starting from the
    scenario's step size, with the highest-order coupling of ``couplings`` (linear unless only the
    hold is chosen). Sample ``i`` is the same plant at every step, order and ``sets`` combination. The
    parameters are ``Grid``'s (``Grid.cases``); ScenarioError (one line) for a value or a case not allowed.
    """
    steps = default_step_sizes() if step_sizes is None else list(dict.fromkeys(step_sizes))
    stop_time = scenario.simulation.stop_time
    for h in steps:
        if isinstance(h, bool) or not isinstance(h, (int, float)) or not (math.isfinite(h) and h > 0):
            raise ScenarioError(f"step size {h!r} is not allowed; allowed: > 0 (s)")
        if h > stop_time:
            raise ScenarioError(f"step size {h:g} s is not allowed: larger than the stop time {stop_time:g} s; "
                                "allowed: 0 < h <= stop time")
    orders = [scenario.simulation.order] if orders is None else [
        one_of(Order, order, "order") for order in dict.fromkeys(orders)]
    own = DISCRETIZATIONS[int(scenario.controller["discretization"])]
    chosen = [one_of(DISCRETIZATIONS, name, "discretization")
              for name in dict.fromkeys([own] if discretizations is None else discretizations)]
    couplings = [scenario.simulation.coupling] if couplings is None else [
        one_of(Coupling, coupling, "coupling") for coupling in dict.fromkeys(couplings)]
    tolerances = list(dict.fromkeys(tolerances))
    for tolerance in tolerances:
        if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or not (
                math.isfinite(tolerance) and tolerance > 0):
            raise ScenarioError(f"tolerance {tolerance!r} is not allowed; allowed: > 0 (m)")
    if not (steps and orders and chosen and couplings):
        raise ScenarioError("a sweep needs at least one step size, one order, one discretization and one coupling")
    axes, keys = [], set()
    for key, values in sets:
        variable = _variable(key, "--set")
        if key in keys or not values:
            raise ScenarioError(f"--set {key}: given twice or without values; allowed: one --set per parameter")
        keys.add(key)
        axes.append([(key, _value(key, variable, value, "--set")) for value in dict.fromkeys(values)])
    for p in perturbations:
        if p.key in keys:
            raise ScenarioError(f"--perturb {p.key}: also given with --set or twice; allowed: one option per parameter")
        keys.add(p.key)
    draws = _draw(scenario, perturbations, samples, seed)
    physical = [(tuple(combo) + drawn, sample) for combo in itertools.product(*axes) for sample, drawn in draws]
    for overrides, sample in physical:  # Assumption 2 and the ranges, once per physical case
        apply(scenario, Case(steps[0], orders[0], chosen[0], overrides, sample))
    fixed = [Case(h, order, name, overrides, sample, coupling) for h in steps for order in orders for name in chosen
             for coupling in couplings for overrides, sample in physical]
    best = max(couplings, key=lambda coupling: coupling.order)
    return fixed + [Case(scenario.simulation.step_size, order, name, overrides, sample, best, tolerance)
                    for tolerance in tolerances for order in orders for name in chosen
                    for overrides, sample in physical]


def apply(scenario: Scenario, case: Case) -> Scenario:
    """The scenario a case runs.

    The scenario's ``input_derivatives`` carries over to a linear fixed-step case only; the others run
    on the FMUs' coupling parameters.

    Parameters
    ----------
    scenario : Scenario
        The sweep's scenario.
    case : Case
        The case to apply.

    Returns
    -------
    Scenario
        ``scenario`` with the case's overrides (checked), its discretisation (as the controller's
        integer ``discretization``), its step size, order, coupling and tolerance.

    Raises
    ------
    ScenarioError
        One line naming what is not allowed, if an override of the case is not.
    """
    where = scenario.source
    tables = {name: dict(getattr(scenario, name)) for name in TABLES}
    for key, value in case.overrides:
        variable = _variable(key, f"{where}:")
        value = _value(key, variable, value, f"{where}:")
        table = key.partition(".")[0]
        tables[table][variable.name] = variable.choices.index(value) if variable.choices else value
    tables["controller"]["discretization"] = DISCRETIZATIONS.index(case.discretization)
    changed = dataclasses.replace(scenario, **tables)
    routed = changed.simulation.input_derivatives and case.coupling == Coupling.LINEAR and case.tolerance is None
    changed = dataclasses.replace(changed, simulation=dataclasses.replace(
        changed.simulation, tolerance=case.tolerance, input_derivatives=routed))
    return changed.with_simulation(step_size=case.step_size, order=case.order, coupling=case.coupling)


@dataclass(frozen=True)
class Grid:
    """What a step-size study varies; ``cases`` checks it against a scenario and makes its cases.

    Parameters
    ----------
    step_sizes : sequence of float, optional
        Communication steps in s. Default ``default_step_sizes()``.
    orders : sequence of str, optional
        Coupling orders (``ORDERS``). Default both; None: the scenario's.
    discretizations : sequence of str, optional
        Controller discretisations (``DISCRETIZATIONS``). Default: the scenario's.
    couplings : sequence of str, optional
        Couplings of the fixed-step runs (``COUPLINGS``). Default both; None: the scenario's.
    tolerances : sequence of float, optional
        Tolerances of the error-controlled runs in m. Default ``DEFAULT_TOLERANCES``; empty for none.
    sets : sequence of tuple, optional
        Scenario values to vary too, as ``(key, values)`` pairs (``parse_set``). Default none.
    perturbations : sequence of Perturbation, optional
        Plant parameters drawn per Monte Carlo sample (``parse_perturb``). Default none.
    samples : int or None, optional
        Number of Monte Carlo samples; needs ``perturbations``. Default None (no sampling).
    seed : int, optional
        Seed of the draws (``numpy.random.default_rng``). Default 0.
    """

    step_sizes: tuple | None = tuple(default_step_sizes())
    orders: tuple | None = ORDERS
    discretizations: tuple | None = None
    couplings: tuple | None = COUPLINGS
    tolerances: tuple = DEFAULT_TOLERANCES
    sets: tuple = ()
    perturbations: tuple = ()
    samples: int | None = None
    seed: int = 0

    def cases(self, scenario: Scenario) -> list[Case]:
        """The grid's cases on ``scenario`` (``build_cases``).

        Parameters
        ----------
        scenario : Scenario
            The scenario the cases apply to.

        Returns
        -------
        list of Case
            Every case of the grid, fixed-step ones first.

        Raises
        ------
        ScenarioError
            One line naming what is not allowed, if a value of the grid or a case is not.
        """
        return build_cases(scenario, self.step_sizes, self.orders, self.discretizations, self.sets, self.perturbations,
                           self.samples, self.seed, self.couplings, self.tolerances)


_SCHEDULER_ALLOWED = "allowed: tcp://HOST:PORT or tls://HOST:PORT with PORT a whole number in 1..65535"


def parse_scheduler(address: str) -> tuple[str, str, int]:
    """``(protocol, host, port)`` of a Dask scheduler address ``tcp://HOST:PORT`` or ``tls://HOST:PORT``
    (``HOST:PORT`` alone is tcp, ``[IPv6]:PORT`` in brackets, as for ``distributed.comm.parse_address``);
    else SweepError (one line).

    >>> parse_scheduler("tcp://10.0.0.5:8786"), parse_scheduler("tls://[::1]:8786")
    (('tcp', '10.0.0.5', 8786), ('tls', '::1', 8786))
    """
    protocol, separator, location = address.partition("://")
    if not separator:
        protocol, location = "tcp", address
    if location.startswith("["):
        host, bracket, rest = location[1:].partition("]")
        port = rest[1:] if bracket and rest.startswith(":") else None
    else:
        host, colon, port = location.rpartition(":") if ":" in location else (location, "", None)
    if protocol not in ("tcp", "tls"):
        why = f"the protocol {protocol!r} is not supported"
    elif not host:
        why = "no host"
    elif not port:
        why = "no port"
    elif not (port.isascii() and port.isdigit()):
        why = f"the port {port!r} is not a whole number"
    elif not 1 <= int(port) <= 65535:
        why = f"the port {port} is out of range"
    else:
        return protocol, host, int(port)
    raise SweepError(f"Dask scheduler address {address!r} is not allowed: {why}; {_SCHEDULER_ALLOWED}")


def check_scheduler(address: str, timeout: float) -> None:
    """Check that a Dask scheduler's host accepts a TCP connection on its port.

    Run it before ``distributed.Client``: a client of an address that is wrong or closed stalls for
    its own timeout, then complains when collected.
    """
    _, host, port = parse_scheduler(address)
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as error:
        reason = error.strerror or str(error) or type(error).__name__
        raise SweepError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s: {reason}") from None


@dataclass(frozen=True)
class Runner:
    """Where and how a sweep's runs go, checked when it is made.

    Parameters
    ----------
    jobs : int or None, optional
        Local worker processes, each loading the FMUs once; 1 runs in this process. Default None:
        ``os.cpu_count()``. Does not apply with ``scheduler``.
    scheduler : str or None, optional
        Address of a Dask scheduler (``parse_scheduler``) to send the runs to instead. Default None.
    scheduler_timeout : float, optional
        How long to wait for the scheduler to answer, in s. Default ``SCHEDULER_TIMEOUT``.
    progress : bool, optional
        Show a progress line on a terminal (``cosim.progress.ProgressLine``). Default True.

    Raises
    ------
    SweepError
        One line naming what is allowed, if ``jobs`` is not a whole number >= 1 or ``scheduler`` not
        an address.
    """

    jobs: int | None = None
    scheduler: str | None = None
    scheduler_timeout: float = SCHEDULER_TIMEOUT
    progress: bool = True

    def __post_init__(self):
        jobs = self.jobs
        if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
            raise SweepError(f"jobs = {jobs!r} is not allowed; allowed: a whole number >= 1")
        if self.scheduler is not None:
            parse_scheduler(self.scheduler)
