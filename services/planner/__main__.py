"""``python -m services.planner --config FILE``."""

import sys

from services.planner.service import main

sys.exit(main())
