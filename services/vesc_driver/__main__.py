"""``python -m services.vesc_driver --config FILE``."""

import sys

from services.vesc_driver.service import main

sys.exit(main())
