"""``python -m sharedspace.marl``: one multi-car training run (:mod:`sharedspace.marl.train`)."""

import sys

from sharedspace.cli import run_command
from sharedspace.marl.train import main

sys.exit(run_command(main))
