"""Build the three FMUs into build/fmus/ (same as ``dsc-fmu build``)."""

import sys

from dsc_fmu.cli import main

if __name__ == "__main__":
    sys.exit(main(["build", *sys.argv[1:]]))
