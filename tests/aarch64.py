"""aarch64 Linux for the tests, under Debian's qemu-user: an arm64 Debian root made by ``mmdebstrap`` from
Debian's packages, with the project's runtime dependencies put into it by the host's pip
(``debian_root.cached_root``: made once per specification and kept in the user's cache). Its tasks (this
file's and ``debian_root``'s) call the same functions the host calls, so the two sides differ in the machine
only. Without a tool the tests skip, except where ``DSC_FMU_CI`` is set (``wine.required``)."""

import sys
from pathlib import Path

from debian_root import DebianRoot, Site, Specification, cached_root, host_versions

PYTHON = "3.11"
# What importing dsc_fmu's master and model exchange and fmpy's simulate_fmu needs (fmpy's other
# requirements serve its GUI, remoting and code generation), pinned to the host's versions.
PYTHON_PACKAGES = ("numpy", "scipy", "fmpy", "attrs", "lxml")
ZIG_TARGET = "aarch64-linux-gnu.2.17"
QEMU_REGISTRATION = Path("/usr/lib/binfmt.d/qemu-aarch64.conf")
BINFMT = Path("/proc/sys/fs/binfmt_misc")
NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")


def compile_for_aarch64(source: str, output: Path) -> Path:
    """Compile ``tests/<source>`` for aarch64 Linux (glibc 2.17), as ``c_hosts.compile_c`` does for x86-64."""
    import subprocess

    import fmpy

    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", ZIG_TARGET, "-O2", "-std=gnu11", f"-I{headers}",
                    "-o", str(output), str(Path(__file__).parent / source), "-D_GNU_SOURCE", "-ldl", "-lpthread"],
                   check=True, capture_output=True, timeout=600)
    return output


def elf_machine(data: bytes) -> int:
    """An ELF file's ``e_machine`` (62 x86-64, 183 aarch64)."""
    assert data[:4] == b"\x7fELF", data[:4]
    return int.from_bytes(data[18:20], "little")


def _register_qemu() -> None:
    """binfmt_misc mounted and qemu-aarch64 registered (Debian's registration, whose F flag lets a chroot
    use the interpreter), as root."""
    import subprocess

    from wine import required

    if not (BINFMT / "register").exists():
        mount = subprocess.run(["mount", "-t", "binfmt_misc", "binfmt_misc", str(BINFMT)], capture_output=True,
                               text=True)
        if mount.returncode != 0:
            required(f"binfmt_misc cannot be mounted: {mount.stderr.strip()}")
    entry = BINFMT / "qemu-aarch64"
    if not entry.exists():
        (BINFMT / "register").write_text(QEMU_REGISTRATION.read_text().strip() + "\n")
    lines = entry.read_text().splitlines()
    if lines[0] != "enabled":
        entry.write_text("1")
    flags = next(line.split()[1] for line in lines if line.startswith("flags:"))
    if "F" not in flags:
        required(f"qemu-aarch64 is registered without the F flag ({flags}): a chroot cannot reach the interpreter")


def specification() -> Specification:
    """The arm64 root: Debian 12's CPython 3.11 and the host's versions of ``PYTHON_PACKAGES``."""
    return Specification("aarch64", "bookworm", (f"python{PYTHON}", f"libpython{PYTHON}", "libstdc++6"),
                         (Site(PYTHON, ("manylinux_2_28_aarch64", "manylinux2014_aarch64"),
                               host_versions(PYTHON_PACKAGES)),), architecture="arm64")


def cached_arm64_root() -> DebianRoot:
    """The arm64 Debian root, from the cache or made there (as root: mmdebstrap, Debian's qemu-user-static,
    chroot), with qemu-aarch64 registered."""
    import os

    from wine import required

    if os.geteuid() != 0:
        required("the aarch64 root needs root (mount, chroot)")
    if not QEMU_REGISTRATION.is_file():
        required("qemu-user-static is not installed (Debian: apt-get install qemu-user-static)")
    return cached_root(specification(), prepare=_register_qemu)


def bundled_runtime(fmus: dict) -> dict:
    """What ``--bundle-python`` carries when built here for the one FMU of ``fmus``: this platform, the
    platforms an FMU built here can carry a CPython for, the runtimes made for this platform, and the ELF
    machine of each library of this platform's runtime."""
    import zipfile

    from dsc_fmu.fmubuild.binary import TARGETS, ENTRY_FILE, host_target
    from dsc_fmu.fmubuild.bundle import bundled_runtimes, carried_platforms

    (path,) = fmus.values()
    with zipfile.ZipFile(path) as fmu:
        entry = " ".join(fmu.read(f"resources/{ENTRY_FILE}").decode().split()[:2])
    here = host_target().name
    runtimes = bundled_runtimes(Path(path), entry, True, [target.name for target in TARGETS if target.os == "linux"])
    runtime = runtimes[here]
    return {"host": here, "carried": carried_platforms([target.name for target in TARGETS]),
            "platforms": sorted(runtimes), "os": runtime.os, "needs": list(runtime.needs), "licences": sorted(runtime.licences),
            "machines": {name: elf_machine(data) for name, data in runtime.files.items() if ".so" in name}}


def ssp_in_fmpy(fmus: dict) -> dict:
    """``run_simulate_ssp`` of the SSP archive that is the one file of ``fmus``: the error it raises."""
    from dsc_fmu.interop.ssp import SSPError, run_simulate_ssp

    (archive,) = fmus.values()
    try:
        run_simulate_ssp(archive, 1e-3, 0.01)
    except SSPError as error:
        return {"error": str(error)}
    return {"error": None}
