"""``python -m optitact.cli``."""

import sys

from optitact.cli import main

sys.exit(main())
