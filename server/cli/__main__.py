"""`python -m sphrender.server.cli` = `sphrender`."""

import sys

from sphrender.server.cli import main

sys.exit(main())
