"""dsc-fmu: the adaptive DSC of an electrically driven mobile robot as FMI FMUs (co-simulation and model exchange).

The names a user needs (``__all__``), imported when first used: ``import dsc_fmu`` and ``dsc-fmu --help`` stay fast.
"""

import importlib

__version__ = "0.1.0"

_EXPORTS = {
    "load_scenario": "dsc_fmu.scenario",
    "build_fmus": "dsc_fmu.fmubuild.fmus",
    "ensure_fmus": "dsc_fmu.fmubuild.fmus",
    "cosimulate": "dsc_fmu.cosim.master",
    "Cosimulator": "dsc_fmu.cosim.master",
    "simulate_model_exchange": "dsc_fmu.cosim.model_exchange",
    "linearise_at": "dsc_fmu.cosim.model_exchange",
    "reference_solution": "dsc_fmu.cosim.reference_solution",
    "run_scenario": "dsc_fmu.cosim.run",
    "run_sweep": "dsc_fmu.study.sweep",
    "compare_adaptation_laws": "dsc_fmu.study.laws",
    "Grid": "dsc_fmu.study.cases",
    "Runner": "dsc_fmu.study.cases",
    "DscFmuError": "dsc_fmu.errors",
    "CosimulationError": "dsc_fmu.errors",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'dsc_fmu' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_EXPORTS])
