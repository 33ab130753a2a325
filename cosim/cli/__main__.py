"""``python -m cosim.cli``: the command line, as the ``cosim`` script runs it."""

import sys

from cosim.cli import main

sys.exit(main())
