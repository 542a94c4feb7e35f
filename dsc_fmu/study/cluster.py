"""A sweep on a Dask cluster (docs/step-size-studies.md): a client of its scheduler, checked first, and the
sweep's FMUs on every worker."""

from __future__ import annotations

import asyncio
import tempfile
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import distributed
from distributed.diagnostics.plugin import WorkerPlugin

from .cases import SweepError, check_scheduler

__all__: list[str] = []  # what the sweep's executor (execute.Workers) uses; nothing for users


async def _identity(address: str) -> dict:
    async with distributed.rpc(address, connection_args=distributed.Security().get_connection_args("client")) as peer:
        return await peer.identity()


def connect(address: str, timeout: float) -> distributed.Client:
    """A client of the Dask scheduler at ``address``, checked first (a client of a server that is not a
    Dask scheduler would wait forever).
    """
    check_scheduler(address, timeout)
    try:
        with ThreadPoolExecutor(1) as thread:  # an event loop of its own, whatever loop the caller runs
            thread.submit(asyncio.run, asyncio.wait_for(_identity(address), timeout)).result()
        return distributed.Client(address, timeout=timeout, set_as_default=False)
    except TimeoutError:
        raise SweepError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s: "
                         "no Dask scheduler answered there") from None
    except (OSError, ValueError, TypeError) as error:
        reason = (str(error).splitlines() or [type(error).__name__])[0]
        raise SweepError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s: {reason}") from None


class FmusOnWorkers(WorkerPlugin):
    """Worker plugin: the FMU files written into a folder of each worker's local directory and held there
    by ``place(paths, folder)``, closed when the plugin is unregistered (the sweep ends) or the worker closes.
    """

    def __init__(self, fmu_paths: dict, place: Callable):
        self.blobs = {name: Path(path).read_bytes() for name, path in sorted(fmu_paths.items())}
        self.place, self.fmus = place, None
        self.name = f"dsc-fmu-{uuid.uuid4().hex}"  # one per sweep: a plugin of the same name would replace it

    def setup(self, worker) -> None:
        folder = Path(tempfile.mkdtemp(prefix="dsc_fmu_sweep_", dir=worker.local_directory))
        for name, data in self.blobs.items():
            (folder / f"{name}.fmu").write_bytes(data)
        self.fmus = self.place({name: folder / f"{name}.fmu" for name in self.blobs}, folder)

    def teardown(self, worker) -> None:
        if self.fmus is not None:
            self.fmus.close()


def on_worker(name: str, fn: Callable, applied):
    """Dask task: ``fn`` computed with this worker's FMUs (``place.compute``)."""
    return distributed.get_worker().plugins[name].fmus.compute(fn, applied)
