"""``python -m services.telemetry --config FILE [--out DIR] [--serve PORT] [--viewer]``."""

import sys

from services.telemetry.service import main

sys.exit(main())
