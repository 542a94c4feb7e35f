"""The plant, the reference robot and the adaptive DSC law in plain Python (standard library only).

This package is bundled into every FMU: it must import nothing outside the standard library.
"""
