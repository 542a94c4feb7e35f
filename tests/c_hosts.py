"""The project's C importers (``c_importer.c``: FMUs of one model side by side; ``c_master.c``: the paper's
loop; ``c_threads.c``: one FMU called from several threads) built and run as a C tool without Python
runs them: compiled with Zig's C compiler from the package index, started with an empty environment
from another working directory."""

import subprocess
import sys
from pathlib import Path

from fmpy import read_model_description

from dsc_fmu.models import parameters as P

HERE = Path(__file__).parent
EMPTY_ENVIRONMENT = {"PATH": "/usr/bin:/bin"}


def compile_c(source: str, output: Path, windows: bool = False) -> Path:
    """Compile ``tests/<source>`` into the executable ``output`` (FMI headers as FMPy ships them), for
    x86-64 Windows if ``windows``."""
    import fmpy

    headers = Path(fmpy.__file__).parent / "c-code"
    target = ["-target", "x86_64-windows-gnu"] if windows else ["-D_GNU_SOURCE", "-ldl", "-lpthread"]
    subprocess.run([sys.executable, "-m", "ziglang", "cc", "-O2", "-std=gnu11", f"-I{headers}", "-o", str(output),
                    str(HERE / source), *target], check=True, capture_output=True, timeout=600)
    return output


def run_c(command: list, cwd: Path, env: dict | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run a C host with ``env`` (default: empty but for PATH) in ``cwd``."""
    return subprocess.run([str(c) for c in command], cwd=cwd, env=env or EMPTY_ENVIRONMENT, capture_output=True,
                          text=True, timeout=timeout)


def write_plan(path: Path, unzipped: dict, steps: int, step_size: float, order: str, threads: bool, every: int,
               record: dict, locate=str) -> Path:
    """The plan of ``c_master``: the three unzipped FMUs (each folder as ``locate`` writes it for the
    host: the path, or its Windows form), their connections, the run, the recorded outputs."""
    md = {name: read_model_description(str(folder)) for name, folder in unzipped.items()}
    vr = {name: {v.name: v.valueReference for v in m.modelVariables} for name, m in md.items()}
    plant, reference, controller = vr["MobileRobot"], vr["ReferenceRobot"], vr["DSCController"]
    lines = [f"fmu {i} {locate(unzipped[name])} {name} {md[name].guid}"
             for i, name in enumerate(("ReferenceRobot", "MobileRobot", "DSCController"))]
    refs = lambda table, names: " ".join(str(table[n]) for n in names)  # noqa: E731
    lines += [
        f"plant_out {refs(plant, [v.name for v in P.PLANT_OUTPUTS])}",
        f"ref_out {refs(reference, [v.name for v in P.REFERENCE_OUTPUTS])}",
        f"ctl_in {refs(controller, [v.name for v in P.CONTROLLER_INPUTS])}",
        f"ctl_u {refs(controller, ['u1', 'u2'])}",
        f"plant_u {refs(plant, ['u1', 'u2'])}",
    ]
    for index, name in enumerate(("ReferenceRobot", "MobileRobot", "DSCController")):
        if record.get(name):
            lines.append(f"record {index} {refs(vr[name], record[name])}")
    lines.append(f"run {steps} {step_size!r} {order} {int(threads)} {every}")
    path.write_text("\n".join(lines) + "\n")
    return path


def parse_rows(stdout: str) -> list[list[float]]:
    return [[float(value) for value in line.split(",")] for line in stdout.splitlines()]
