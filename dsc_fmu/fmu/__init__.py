"""Everything bundled into an FMU besides the models: the slave core, what each FMU computes, the FMI 2.0
and 3.0 glue and the bridge the binary layer calls. Standard library and ``models`` only."""
