"""Building the FMUs: staging the bundled code, completing the model descriptions, documentation,
and compiling the binary layer (``native``)."""
