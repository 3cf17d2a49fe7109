"""``python -m controller.fmu build|check|crosscheck|cosim ...``"""

import sys

from .cli import main

sys.exit(main())
