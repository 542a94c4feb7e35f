"""dsc-fmu: the adaptive DSC of an electrically driven mobile robot as FMI co-simulation FMUs."""

__version__ = "0.1.0"
