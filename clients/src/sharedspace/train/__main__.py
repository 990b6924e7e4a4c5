"""``python -m sharedspace.train``: see :mod:`sharedspace.train.train`."""

import sys

from sharedspace.cli import run_command
from sharedspace.train.train import main

sys.exit(run_command(main))
