"""Everything bundled into an FMU besides the models: the slave core, what each FMU computes, one glue over
FMI 2.0 and 3.0 and the bridge the binary layer calls. Standard library, ``models`` and the FMI library
the FMU carries only."""
