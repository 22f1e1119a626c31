"""``python -m liethermo``: the command line (``liethermo --help``)."""

import sys

from .cli import entry

sys.exit(entry())
