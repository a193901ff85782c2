"""``python -m services.ros2_gateway --config FILE``."""

import sys

from services.ros2_gateway.service import main

sys.exit(main())
