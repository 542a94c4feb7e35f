"""The three FMUs loaded together for a master: each extracted and instantiated, all closed as one."""

from __future__ import annotations

import shutil
from pathlib import Path

from ..identity import fmu_build_id
from ..registry import ORDER, fmu_files
from .instance import LoadedFmu, LogMessage, load_fmu, logging_callbacks

__all__: list[str] = []  # the package's own: LoadedFmus


class LoadedFmus:
    """The three FMUs of ``registry.ORDER`` loaded (``instance.load_fmu``), their messages going to one log.

    If one cannot be loaded (FmuNotFoundError, CosimulationError), those loaded before it are closed. ``close`` (or
    leaving the ``with`` block) terminates and frees every instance and removes the extracted folders."""

    def __init__(self, fmu_paths: dict, workdir: Path | None, log: list[LogMessage], *, model_exchange: bool = False):
        self.paths = fmu_files(fmu_paths)
        self.callbacks = logging_callbacks(log)  # the run's logger, not fmpy's process-wide proxy
        self.loaded: list[LoadedFmu] = []
        try:
            for name in ORDER:
                self.loaded.append(load_fmu(name, self.paths[name], workdir, log, self.callbacks, model_exchange))
        except BaseException:
            self.close()
            raise
        self.by_name = {fmu.name: fmu for fmu in self.loaded}

    def __enter__(self) -> LoadedFmus:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def records(self) -> dict:
        """Each FMU's ``path`` and ``build_id`` (``identity.fmu_build_id``), by name, as new dicts."""
        return {name: {"path": str(path), "build_id": fmu_build_id(path)} for name, path in self.paths.items()}

    def renew(self) -> None:
        """Bring every used instance back to its state after instantiation (``LoadedFmu.renew``)."""
        for fmu in self.loaded:
            fmu.renew(self.callbacks)

    def close(self) -> None:
        """Close every FMU, last loaded first, removing all their folders even if one fails (idempotent)."""
        try:
            while self.loaded:
                self.loaded.pop().close()
        finally:
            for fmu in self.loaded:
                shutil.rmtree(fmu.folder, ignore_errors=True)
