"""``python -m service.cli``."""

import sys

from service.cli.dispatch import main

sys.exit(main())
