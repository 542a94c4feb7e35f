"""Runs in libcosim (libcosimpy 0.0.6): an SSP archive of the closed loop (``run_libcosim``), or one FMU
alone: the closed-loop container FMU, or a cross-check FMU replayed with its input file.

``python -m dsc_fmu.interop.libcosim`` (``main``) runs one FMU in a process of its own and saves the result as
``.npy`` (docs/other-tools.md: why libcosim runs get their own processes). When libcosim samples, when an
override takes effect and how it counts time: docs/other-tools.md, "How the other masters exchange"."""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from ctypes import POINTER, c_double, c_int, c_int64, c_size_t, c_uint32
from pathlib import Path

import numpy as np

from ..cosim import signals
from ..errors import DscFmuError
from ..registry import ORDER
from .libcosim_install import require_libcosimpy
from .ssp import SSPError

__all__ = ["run_libcosim", "run_libcosim_fmu", "run_libcosim_fmu_in_own_process"]

NANO = 1_000_000_000


def _nanoseconds(seconds: float) -> int:
    return int(round(seconds * NANO))


def _samples(observer, slave: int, reference: int, count: int, integer: bool):
    """All samples of one observed variable (the libcosimpy wrapper drops the sample of step 0)."""
    from libcosimpy._internal import libcosimc, wrap_function
    from libcosimpy.CosimObserver import CosimObserver

    c_type = c_int if integer else c_double
    function = wrap_function(
        lib=libcosimc(), funcname="cosim_observer_slave_get_integer_samples" if integer
        else "cosim_observer_slave_get_real_samples",
        argtypes=[POINTER(CosimObserver), c_int, c_uint32, c_int64, c_size_t, c_type * count, c_int64 * count,
                  c_int64 * count],
        restype=c_int64,
    )
    values, steps, times = (c_type * count)(), (c_int64 * count)(), (c_int64 * count)()
    got = function(observer.ptr(), slave, reference, 0, count, values, steps, times)
    if got < 0:
        raise SSPError(f"libcosim: cannot read the samples of variable {reference} of slave {slave}")
    return np.array(times[:got], dtype=np.int64), np.array(steps[:got]), np.array(values[:got], dtype=float)


def _watch(execution, observer, index: int, names, where: str) -> list[tuple[str, int, int, bool]]:
    """Start a time series of each variable of ``names`` of slave ``index`` (``where``: its name for
    messages); (name, slave, value reference, integer) of each."""
    from libcosimpy.CosimEnums import CosimVariableType

    described = {v.name.decode(): v for v in execution.slave_variables(index)}
    watched = []
    for name in names:
        v = described.get(name)
        if v is None:
            raise SSPError(f"{where} has no variable {name!r}")
        integer = v.type == CosimVariableType.INTEGER.value
        if not observer.start_time_series(index, v.reference, CosimVariableType.INTEGER if integer
                                          else CosimVariableType.REAL):
            raise SSPError(f"libcosim: cannot observe {where}.{name}")
        watched.append((name, index, v.reference, integer))
    return watched


def _observed(observer, watched, steps: int, dtype) -> np.ndarray:
    """A row of ``time`` (s) and every watched variable after initialisation and after each of the ``steps``
    steps, else SSPError."""
    result = np.zeros(steps + 1, dtype=dtype)
    for k, (name, index, reference, integer) in enumerate(watched):
        t, step_numbers, values = _samples(observer, index, reference, steps + 16, integer)
        if not np.array_equal(step_numbers, np.arange(steps + 1)):
            raise SSPError(f"libcosim: {name} has samples of the steps {step_numbers[:3]}...; expected 0..{steps}")
        if k == 0:
            result["time"] = t / NANO
        result[name] = values
    return result


def run_libcosim(ssp_file: Path | str, step_size: float, stop_time: float) -> np.ndarray:
    """Co-simulate an SSP archive of the closed loop with libcosim's fixed-step algorithm.

    Parameters
    ----------
    ssp_file : pathlib.Path or str
        The archive, with the three components of ``registry.ORDER`` (``export_ssp``).
    step_size, stop_time : float
        The communication step (rounded to whole ns) and the stop time (rounded up to a whole number of
        steps), in s.

    Returns
    -------
    numpy.ndarray
        A row (dtype ``cosim.signals.DTYPE``) as libcosim's time series observer samples them: at t = 0 after
        initialisation, then after every step.

    Raises
    ------
    SSPError
        If the archive's components are not the three FMUs, a variable cannot be observed or libcosim fails.
    LibcosimUnavailableError
        If libcosimpy is not installed (the extra ``libcosim``).
    """
    require_libcosimpy("run_libcosim")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver

    h = _nanoseconds(step_size)
    steps = -(-_nanoseconds(stop_time) // h)
    execution = CosimExecution.from_ssp_file(str(Path(ssp_file).resolve()), step_size=h)
    slaves = {info.name.decode(): info.index for info in execution.slave_infos()}
    if set(slaves) != set(ORDER):
        raise SSPError(f"{ssp_file}: libcosim found the components {sorted(slaves)}; expected {sorted(ORDER)}")
    observer = CosimObserver.create_time_series(buffer_size=steps + 16)
    execution.add_observer(observer)
    watched = [w for name in ORDER for w in _watch(execution, observer, slaves[name], signals.RECORDED[name], name)]
    if not execution.simulate_until(steps * h):
        from libcosimpy._internal import get_last_error_message

        raise SSPError(f"libcosim failed: {get_last_error_message()}")
    result = _observed(observer, watched, steps, signals.DTYPE)
    signals.add_tracking_errors(result)
    return result


def _held_row(times: np.ndarray, t: float, h: float) -> int:
    """The row of a sample-and-hold table (stamps in s, non-decreasing, repeated where the value
    jumps) that holds over the step from ``t``: the last stamped ``<= t`` within ``h * 1e-6``; SSPError if none."""
    row = int(np.searchsorted(times, t + h * 1e-6, side="right")) - 1
    if row < 0:
        raise SSPError(f"the input table starts at {times[0]!r} s, after {t!r} s")
    return row


def run_libcosim_fmu(fmu_path: Path | str, step_size: float, stop_time: float, outputs, *,
                     inputs: np.ndarray | None = None, instance_name: str = "fmu") -> np.ndarray:
    """Run one co-simulation FMU alone in libcosim at a fixed step, with its start values.

    Parameters
    ----------
    fmu_path : pathlib.Path or str
        The FMU file.
    step_size, stop_time : float
        The communication step (rounded to whole ns) and the stop time (rounded up to a whole number of
        steps), in s.
    outputs : sequence of str
        The names of the variables to record.
    inputs : numpy.ndarray or None, optional
        Real inputs: ``time`` (s) and a column per input (``fmpy.util.read_csv`` of a cross-check
        ``<Model>_in.csv``), sample-and-hold: the values at ``t_0`` set as initial values, later ones by
        libcosim's override manipulator before each step. Default None: no inputs.
    instance_name : str, optional
        The FMU's instance name. Default "fmu".

    Returns
    -------
    numpy.ndarray
        ``time`` (s) and ``outputs``: a row after initialisation, then one after each step, stamped with its end.

    Raises
    ------
    SSPError
        If libcosim cannot load the FMU, a name is not a variable (or a column not a Real input) of it, the
        table starts after 0, or libcosim fails.
    LibcosimUnavailableError
        If libcosimpy is not installed (the extra ``libcosim``).
    """
    require_libcosimpy("run_libcosim_fmu")
    from libcosimpy.CosimEnums import CosimVariableCausality, CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    h = _nanoseconds(step_size)
    steps = -(-_nanoseconds(stop_time) // h)
    execution = CosimExecution.from_step_size(step_size=h)
    slave = CosimLocalSlave(fmu_path=str(Path(fmu_path).resolve()), instance_name=instance_name)
    index = execution.add_local_slave(local_slave=slave)
    if index < 0:
        from libcosimpy._internal import get_last_error_message

        raise SSPError(f"libcosim cannot load {fmu_path}: {get_last_error_message()}")
    observer = CosimObserver.create_time_series(buffer_size=steps + 16)
    execution.add_observer(observer=observer)
    watched = _watch(execution, observer, index, outputs, str(fmu_path))
    described = {v.name.decode(): v for v in execution.slave_variables(index)}

    fed, manipulator = [], None
    if inputs is not None:
        names = [n for n in inputs.dtype.names if n != "time"]
        for name in names:
            v = described.get(name)
            if v is None or v.causality != CosimVariableCausality.INPUT.value:
                raise SSPError(f"{fmu_path}: {name!r} is not an input of the FMU")
            if v.type != CosimVariableType.REAL.value:
                raise SSPError(f"{fmu_path}: input {name!r} is not a Real (only Real inputs are fed)")
        fed = [(name, described[name].reference) for name in names]
        times = np.asarray(inputs["time"], dtype=float)
        row = inputs[_held_row(times, 0.0, step_size)]
        for name, reference in fed:
            if not execution.real_initial_value(index, reference, float(row[name])):
                raise SSPError(f"libcosim: cannot set the initial value of {name}")
        manipulator = CosimManipulator.create_override()
        execution.add_manipulator(manipulator=manipulator)

    references = [reference for _, reference in fed]
    for k in range(steps):
        if k > 0 and fed:
            row = inputs[_held_row(times, k * h / NANO, step_size)]
            if not manipulator.slave_real_values(index, references, [float(row[n]) for n, _ in fed]):
                raise SSPError(f"libcosim: cannot override the inputs at step {k}")
        if not execution.step():
            from libcosimpy._internal import get_last_error_message

            raise SSPError(f"libcosim failed at step {k} (t = {k * h / NANO!r} s): {get_last_error_message()}")

    return _observed(observer, watched, steps, [("time", np.float64)] + [(n, np.float64) for n in outputs])


def run_libcosim_fmu_in_own_process(fmu_path: Path | str, step_size: float, stop_time: float, outputs, *,
                                    inputs_csv: Path | str | None = None, timeout: float = 600) -> np.ndarray:
    """``run_libcosim_fmu`` in a child process (``python -m dsc_fmu.interop.libcosim``).

    Parameters
    ----------
    fmu_path : pathlib.Path or str
        The FMU file.
    step_size, stop_time : float
        The communication step and the stop time, in s.
    outputs : sequence of str
        The names of the variables to record.
    inputs_csv : pathlib.Path or str or None, optional
        A CSV file of inputs in the cross-check format (``run_libcosim_fmu``'s ``inputs``). Default None.
    timeout : float, optional
        How long the child may run, in s. Default 600.

    Returns
    -------
    numpy.ndarray
        As from ``run_libcosim_fmu``.

    Raises
    ------
    SSPError
        If the child fails, with the end of its error output.
    LibcosimUnavailableError
        If libcosimpy is not installed: checked before the child starts.
    subprocess.TimeoutExpired
        If the child runs longer than ``timeout``.
    """
    require_libcosimpy("run_libcosim_fmu_in_own_process")
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_libcosim_") as tmp:
        out = Path(tmp) / "result.npy"
        command = [sys.executable, "-m", "dsc_fmu.interop.libcosim", str(fmu_path), repr(float(step_size)),
                   repr(float(stop_time)), str(out), "--outputs", ",".join(outputs)]
        if inputs_csv is not None:
            command += ["--inputs", str(inputs_csv)]
        child = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        if child.returncode != 0 or not out.is_file():
            raise SSPError(f"libcosim run of {fmu_path} failed (exit code {child.returncode}): "
                           f"{child.stderr[-2000:]}{child.stdout[-2000:]}")
        return np.load(out)


def main(argv=None) -> int:
    """``python -m dsc_fmu.interop.libcosim FMU STEP STOP OUT.npy --outputs a,b [--inputs in.csv]``: exit code 0, or
    1 after a ``DscFmuError`` (libcosimpy missing, an FMU libcosim refuses), printed as ``dsc-fmu: error: ...``."""
    parser = argparse.ArgumentParser(prog="python -m dsc_fmu.interop.libcosim", description=__doc__.splitlines()[0])
    parser.add_argument("fmu")
    parser.add_argument("step_size", type=float)
    parser.add_argument("stop_time", type=float)
    parser.add_argument("out", help="result file (.npy)")
    parser.add_argument("--outputs", required=True, help="comma-separated output names")
    parser.add_argument("--inputs", help="input table (CSV, the cross-check format)")
    args = parser.parse_args(argv)
    try:
        require_libcosimpy("python -m dsc_fmu.interop.libcosim")
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

        log_output_level(CosimLogLevel.WARNING)
        inputs = None
        if args.inputs:
            from fmpy.util import read_csv

            inputs = read_csv(args.inputs)
        result = run_libcosim_fmu(args.fmu, args.step_size, args.stop_time, args.outputs.split(","), inputs=inputs)
    except DscFmuError as error:
        print(f"dsc-fmu: error: {error}", file=sys.stderr)
        return 1
    np.save(args.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
