"""The three FMUs, their variable tables and how they connect: every other module asks here.

>>> ORDER
('ReferenceRobot', 'MobileRobot', 'DSCController')
>>> [c for c in CONNECTIONS if c.end == PLANT]
[Connection(start='DSCController', signal='u1', end='MobileRobot'), Connection(start='DSCController', signal='u2', end='MobileRobot')]
>>> sorted({c.start for c in CONNECTIONS if c.end == CONTROLLER})
['MobileRobot', 'ReferenceRobot']
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .errors import FmuNotFoundError
from .models.states import (
    CONTROLLER_STATES, EVENT_INDICATORS, FILTER_STATES, PLANT_EVENT_INDICATORS, PLANT_STATES, REFERENCE_STATES,
)
from .models.parameters import (
    CONTROLLER_INPUTS,
    CONTROLLER_OUTPUTS,
    CONTROLLER_PARAMETERS,
    DRIVE_OUTPUTS,
    PLANT_INPUTS,
    PLANT_OUTPUTS,
    PLANT_PARAMETERS,
    REFERENCE_OUTPUTS,
    REFERENCE_PARAMETERS,
)

__all__ = ["REFERENCE", "PLANT", "CONTROLLER", "ORDER", "FmuSpec", "FMUS", "CONNECTIONS"]

REFERENCE, PLANT, CONTROLLER = "ReferenceRobot", "MobileRobot", "DSCController"
ORDER = (REFERENCE, PLANT, CONTROLLER)
"""The order of the FMUs everywhere they are listed: loading, stepping, the SSD and the container."""

_POSE = ("x", "y", "theta", "x_r", "y_r")
_ALL_CONTROLLER_INPUTS = tuple(v.name for v in CONTROLLER_INPUTS)


@dataclass(frozen=True)
class FmuSpec:
    """One FMU: its script, its variable tables and what model exchange needs of it.

    Parameters
    ----------
    name : str
        The FMU's model name (``REFERENCE``, ``PLANT``, ``CONTROLLER``).
    script : str
        Its FMI 2.0 slave script in ``fmu_sources`` (``<stem>_fmi3.py`` is the FMI 3.0 one).
    parameters, inputs, outputs : tuple of models.parameters.Variable
        Its variable tables.
    states : tuple of models.states.ContinuousState
        Its continuous states, for model exchange.
    state_locals : tuple of models.parameters.Variable, optional
        The states' variables that are not outputs.
    indicators : tuple of models.parameters.Variable, optional
        Its event indicators.
    depends : dict, optional
        Each discrete output's inputs (ModelStructure); one not listed depends on none.
    """

    name: str
    script: str
    parameters: tuple
    inputs: tuple
    outputs: tuple
    states: tuple
    state_locals: tuple = ()
    indicators: tuple = ()
    depends: dict = field(default_factory=dict)

    def script_for(self, fmi_version: int) -> str:
        """The slave script of an FMI version.

        Parameters
        ----------
        fmi_version : {2, 3}
            The FMI version.

        Returns
        -------
        str
            The script's file name in ``fmu_sources``.
        """
        return f"{Path(self.script).stem}_fmi3.py" if fmi_version == 3 else self.script

    @property
    def locals(self) -> tuple:
        """The local variables in the order the slave registers them: states that are not outputs, derivatives, indicators."""
        return (*self.state_locals, *(s.derivative for s in self.states), *self.indicators)

    @property
    def variables(self) -> dict:
        """Every table variable by name: parameters, inputs, outputs, locals."""
        return {v.name: v for v in (*self.parameters, *self.inputs, *self.outputs, *self.locals)}


FMUS = {
    spec.name: spec
    for spec in (
        FmuSpec(REFERENCE, "reference_robot.py", REFERENCE_PARAMETERS, (), REFERENCE_OUTPUTS, REFERENCE_STATES),
        FmuSpec(
            PLANT, "mobile_robot.py", PLANT_PARAMETERS, PLANT_INPUTS, (*PLANT_OUTPUTS, *DRIVE_OUTPUTS), PLANT_STATES,
            indicators=PLANT_EVENT_INDICATORS, depends={"saturation_active": ("u1", "u2")},
        ),
        FmuSpec(
            CONTROLLER, "dsc_controller.py", CONTROLLER_PARAMETERS, CONTROLLER_INPUTS, CONTROLLER_OUTPUTS,
            CONTROLLER_STATES, FILTER_STATES, EVENT_INDICATORS,
            depends={
                "beta_guard_active": (*_POSE, "v_r"),
                "started": _ALL_CONTROLLER_INPUTS,
            },
        ),
    )
}


@dataclass(frozen=True)
class Connection:
    """The output ``signal`` of FMU ``start`` feeds the input of the same name of FMU ``end``."""

    start: str
    signal: str
    end: str


def _connections() -> tuple[Connection, ...]:
    """Each input fed by the output of the same name of another FMU: the controller's measurements
    first (in its input order), then the plant's voltages (fmpy's container transfers in this order)."""
    found = []
    for end in (CONTROLLER, PLANT):
        for variable in FMUS[end].inputs:
            start = next(s for s in ORDER if s != end and variable.name in {v.name for v in FMUS[s].outputs})
            found.append(Connection(start, variable.name, end))
    return tuple(found)


CONNECTIONS = _connections()


def fmu_files(fmu_paths: dict) -> dict[str, Path]:
    """The three FMU files of ``fmu_paths`` (FMU name -> path) in ``ORDER``; FmuNotFoundError naming the first not given
    or not a file."""
    paths = {name: Path(fmu_paths.get(name, f"{name}.fmu")) for name in ORDER}
    for name, path in paths.items():
        if name not in fmu_paths or not path.is_file():
            raise FmuNotFoundError(f"{path}: {name} FMU not found; build it with `dsc-fmu build` or dsc_fmu.build_fmus")
    return paths
