"""``python -m controller.cli``: the ``cantrack`` command."""

import sys

from . import main

sys.exit(main())
