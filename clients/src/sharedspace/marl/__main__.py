"""``python -m sharedspace.marl``: one multi-car training run (:mod:`sharedspace.marl.train`)."""

import sys

from sharedspace.marl.train import main

sys.exit(main())
