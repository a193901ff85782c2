"""``python -m services.localization_bridge --config FILE``."""

import sys

from services.localization_bridge.service import main

sys.exit(main())
