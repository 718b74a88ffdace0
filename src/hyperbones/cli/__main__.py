"""``python -m hyperbones.cli``: the command line (as torchrun runs it)."""

import sys

from hyperbones.cli import main

sys.exit(main())
