"""Benchmark: what carrying a CPython costs an FMU (``dsc-fmu build --bundle-python``), in size and in
instantiation time, beside the same FMUs without one.

Sizes are bytes in the FMU archive (compressed), the runtime's share per system summed over its files.
Times are wall times of whole processes of the project's C importer (``tests/c_importer.c``, started
with an empty environment): loading the binary, finding and starting a CPython, importing the FMU's
code, instantiating, initialising and freeing. The first instantiation is a process with one instance:
with the FMU's own CPython, and with the machine's (the same FMU with ``DSC_FMU_PYTHON`` naming the
building CPython, and the FMU without a runtime, which finds the building CPython itself). A later
instantiation is what each further instance of the same FMU adds to such a process (``--instances`` of
them, each from its own unzipped copy, so each loads its own binary). Best of ``--repeat``.
Run: ``python benchmarks/bundle.py [--fmi-version 2] [--repeat 5] [--instances 8]`` (the importer takes 8 at most).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

from fmpy import extract, read_model_description

from dsc_fmu.fmubuild.binary import OVERRIDE_VARIABLE, TARGETS, WINDOWS, host_target
from dsc_fmu.fmubuild.bundle import ROOT
from dsc_fmu.fmubuild.fmus import build_fmus
from dsc_fmu.registry import FMUS

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from c_hosts import EMPTY_ENVIRONMENT, compile_c  # noqa: E402

MB = 1e6


def _runtime_share(fmu: Path, version: int) -> dict[str, int]:
    """The compressed bytes of each platform's runtime in ``fmu``."""
    with zipfile.ZipFile(fmu) as archive:
        return {target.name: sum(item.compress_size for item in archive.infolist()
                                 if item.filename.startswith(f"binaries/{target.folder(version)}/{ROOT}/"))
                for target in TARGETS}


def _sizes(default: dict, bundled: dict, version: int) -> None:
    print(f"FMU size, FMI {version}.0 (MB in the archive)")
    print(f"{'FMU':16}{'without':>10}{'with':>10}{'added':>10}{'Linux':>10}{'Windows':>10}")
    for name in FMUS:
        plain, carried = default[name].stat().st_size, bundled[name].stat().st_size
        share = _runtime_share(bundled[name], version)
        print(f"{name:16}{plain / MB:10.2f}{carried / MB:10.2f}{(carried - plain) / MB:10.2f}"
              f"{share[host_target().name] / MB:10.2f}{share[WINDOWS.name] / MB:10.2f}")


def _process_seconds(host: Path, folders: list[Path], version: int, env: dict, repeat: int) -> float:
    """The best wall time of a C importer process that instantiates one instance from each folder."""
    md = read_model_description(str(folders[0]))
    token = md.guid if version == 2 else md.instantiationToken
    command = [str(host), str(version), ",".join(map(str, folders)), md.coSimulation.modelIdentifier,
               ",".join([token] * len(folders)), "0", "0.001", "0"]
    best = float("inf")
    for _ in range(repeat):
        started = time.perf_counter()
        subprocess.run(command, env=env, capture_output=True, check=True, cwd=folders[0].parent)
        best = min(best, time.perf_counter() - started)
    return best


def _copies(fmu: Path, folder: Path, count: int) -> list[Path]:
    first = Path(extract(str(fmu), unzipdir=folder / "0"))
    return [first, *(Path(shutil.copytree(first, folder / str(i))) for i in range(1, count))]


def _times(host: Path, default: Path, bundled: Path, version: int, tmp: Path, repeat: int, instances: int) -> None:
    own, plain = _copies(bundled, tmp / "bundled", instances), _copies(default, tmp / "default", instances)
    machines = {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: sys.base_prefix}
    routes = (("the FMU's own CPython", own, EMPTY_ENVIRONMENT),
              ("the machine's, named by DSC_FMU_PYTHON", own, machines),
              ("the machine's, FMU without a runtime", plain, EMPTY_ENVIRONMENT))
    print(f"\nInstantiation of {default.stem}, FMI {version}.0 (s, best of {repeat}; "
          f"later: what each of {instances - 1} more instances adds)")
    print(f"{'CPython':42}{'first':>10}{'later':>10}{'first / own':>14}")
    first_own = None
    for label, folders, env in routes:
        first = _process_seconds(host, folders[:1], version, env, repeat)
        later = (_process_seconds(host, folders, version, env, repeat) - first) / (instances - 1)
        first_own = first_own or first
        print(f"{label:42}{first:10.3f}{later:10.4f}{first / first_own:14.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fmi-version", type=int, choices=(2, 3), default=2)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--instances", type=int, default=8, choices=range(2, 9), metavar="2..8")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_bundle_bench_") as tmp:
        tmp = Path(tmp)
        default = build_fmus(tmp / "default", fmi_version=args.fmi_version)
        started = time.perf_counter()
        bundled = build_fmus(tmp / "bundled", fmi_version=args.fmi_version, bundle_python=True)
        print(f"Building the three FMUs with --bundle-python: {time.perf_counter() - started:.1f} s "
              f"(the embeddable CPython cached)\n")
        _sizes(default, bundled, args.fmi_version)
        host = compile_c("c_importer.c", tmp / "c_importer")
        _times(host, default["DSCController"], bundled["DSCController"], args.fmi_version, tmp, args.repeat,
               args.instances)


if __name__ == "__main__":
    main()
