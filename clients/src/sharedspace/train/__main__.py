"""``python -m sharedspace.train``: see :mod:`sharedspace.train.train`."""

import sys

from sharedspace.train.train import main

sys.exit(main())
