"""Build the three FMUs into build/fmus/ (``--fmi-version 3``: FMI 3.0 into build/fmus3/); same as ``dsc-fmu build``."""

import sys

from dsc_fmu.cli import main

if __name__ == "__main__":
    sys.exit(main(["build", *sys.argv[1:]]))
