"""``python -m services.lidar_driver --config FILE``."""

import sys

from services.lidar_driver.service import main

sys.exit(main())
