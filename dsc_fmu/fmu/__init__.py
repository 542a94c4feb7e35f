"""Everything bundled into an FMU besides ``models``: each FMU's model (``model.Model``), the slave that holds it
(``slave``, on FMI 2.0 or 3.0: ``fmi2``, ``fmi3``), its directional derivatives and the bridge the binary layer
calls. Standard library, ``models`` and the FMI library the FMU carries only."""
