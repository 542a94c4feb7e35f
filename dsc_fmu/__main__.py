"""``python -m dsc_fmu``: the ``dsc-fmu`` command line."""

import sys

from .cli import main

sys.exit(main())
