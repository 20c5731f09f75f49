"""``python -m app.cli``: the ``vantage`` command."""

import sys

from app.cli import main

sys.exit(main())
