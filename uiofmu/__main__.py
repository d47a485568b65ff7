"""``python -m uiofmu``."""

import sys

from .cli import main

sys.exit(main())
