"""``python -m ham`` is the ``ham`` command."""

import sys

from ham.cli import main

sys.exit(main())
