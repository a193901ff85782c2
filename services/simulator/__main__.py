"""``python -m services.simulator --config FILE``."""

import sys

from services.simulator.service import main

sys.exit(main())
