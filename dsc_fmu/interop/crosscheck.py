"""FMI cross-check artefacts for the three FMUs (the layout of the fmi-cross-check repository).

Per FMU, ``<Model>.fmu``, ``<Model>_ref.csv``, ``<Model>_in.csv`` (sample-and-hold), ``<Model>_ref.opt`` and
``ReadMe.md`` from one closed-loop Jacobi run, recording what each FMU saw: replaying an FMU alone at the same
step with its input file reproduces its reference (docs/other-tools.md, "How the other masters exchange")."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from .. import __version__

from ..cosim import signals
from ..cosim.exchange import cosimulate_exchange
from ..identity import require_fmi2
from ..registry import ORDER, fmu_files
from ..scenario import Scenario, load_scenario

__all__ = ["write_crosscheck", "DEFAULT_STOP_TIME", "FMI2_ONLY"]

DEFAULT_STOP_TIME = 2.0
FMI2_ONLY = "the FMI cross-check (modelica/fmi-cross-check) takes FMI 1.0 and 2.0 FMUs"
TOOL = "dsc-fmu"


def _model_dir(out_dir: Path, model: str, platform: str = "linux64", version: str = __version__) -> Path:
    """``out_dir/fmus/2.0/cs/<platform>/dsc-fmu/<version>/<model>``: the cross-check folder of one FMU."""
    return Path(out_dir) / "fmus" / "2.0" / "cs" / platform / TOOL / version / model


def _held_inputs(inputs: np.ndarray, stop_time: float) -> np.ndarray:
    """The inputs held over each step (one row per step, ``time`` its start) as two rows a step,
    ``(t_k, v_k)`` and ``(t_k+1, v_k)``."""
    starts = inputs["time"]
    ends = np.append(starts[1:], stop_time)
    rows = np.empty(2 * len(inputs), dtype=inputs.dtype)
    rows[0::2] = inputs
    rows[1::2] = inputs
    rows["time"][1::2] = ends
    return rows


def _write_csv(path: Path, table: np.ndarray) -> None:
    names = table.dtype.names
    with open(path, "w", newline="") as f:
        f.write(",".join(names) + "\n")
        for row in table:
            f.write(",".join(repr(float(row[n])) for n in names) + "\n")


def _readme(model: str, scenario: Scenario, h: float, stop: float, has_inputs: bool) -> str:
    lines = [
        f"# {model}",
        "",
        f"Exported by dsc-fmu {__version__} (pythonfmu 0.7.0): a Python FMU; the importing machine needs a",
        "Python of the version it was built with (it imports only the standard library).",
        "",
        f"Reference: `{model}_ref.csv`, its outputs at every communication point of a closed-loop",
        f"co-simulation of the scenario `{scenario.name}` (the DSC controller, the mobile robot and the",
        f"reference robot, Jacobi coupling at a communication step of {h:g} s) from 0 to {stop:g} s.",
    ]
    if has_inputs:
        lines += [
            "",
            f"Inputs: `{model}_in.csv`, the inputs the FMU held over each step of that run, written",
            "sample-and-hold (a time stamp repeated where the value jumps). Set the inputs at each",
            "communication point to the value after the jump and step with StepSize to reproduce the reference.",
        ]
    lines += ["", "Every parameter keeps its start value (the paper's).", ""]
    return "\n".join(lines)


def write_crosscheck(out_dir: Path | str, fmu_paths: dict, *, scenario: Scenario | None = None,
                     step_size: float | None = None, stop_time: float = DEFAULT_STOP_TIME,
                     platform: str = "linux64") -> dict[str, Path]:
    """Write the cross-check folders ``fmus/2.0/cs/<platform>/dsc-fmu/<version>/<Model>`` of the three FMUs.

    Parameters
    ----------
    out_dir : pathlib.Path or str
        The root of the cross-check tree.
    fmu_paths : dict
        FMU name (``registry.ORDER``) -> path of each of the three FMI 2.0 co-simulation FMUs.
    scenario : Scenario or None, optional
        The closed loop to run, every parameter at its start value (the FMUs are replayed with their
        defaults). Default None: the paper's scenario.
    step_size : float or None, optional
        The communication step, in s. Default None: the scenario's.
    stop_time : float, optional
        The stop time, in s. Default ``DEFAULT_STOP_TIME`` (2 s).
    platform : str, optional
        The cross-check platform name. Default "linux64".

    Returns
    -------
    dict of str to pathlib.Path
        The folder of each FMU by name.

    Raises
    ------
    ScenarioError
        If a simulation setting is bad.
    FmuNotFoundError
        If one of the three FMUs is not given or not a file.
    FmiVersionError
        If an FMU is not an FMI 2.0 FMU (``FMI2_ONLY`` says why); nothing is written.
    """
    require_fmi2(fmu_files(fmu_paths).values(), FMI2_ONLY)
    scenario = scenario or load_scenario("paper")
    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time)
    h, stop = scenario.simulation.step_size, scenario.simulation.stop_time
    run = cosimulate_exchange(scenario, fmu_paths, "jacobi")
    folders = {}
    for name in ORDER:
        folder = _model_dir(Path(out_dir), name, platform)
        folder.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(fmu_paths[name], folder / f"{name}.fmu")
        columns = ["time", *signals.RECORDED[name]]
        reference = np.zeros(len(run.result), dtype=[(c, np.float64) for c in columns])
        source = run.before_inputs.get(name, run.result)
        for c in columns:
            reference[c] = source[c]
        _write_csv(folder / f"{name}_ref.csv", reference)
        has_inputs = name in run.inputs
        if has_inputs:
            _write_csv(folder / f"{name}_in.csv", _held_inputs(run.inputs[name], stop))
        (folder / f"{name}_ref.opt").write_text(
            f"StartTime, 0.0\nStopTime, {stop!r}\nStepSize, {h!r}\nRelTol, 1e-6\n")
        (folder / "ReadMe.md").write_text(_readme(name, scenario, h, stop, has_inputs))
        folders[name] = folder
    return folders

