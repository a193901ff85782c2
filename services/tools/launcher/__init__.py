"""``racestack up``: the stack as one process per service, supervised, racing the simulator.

What other tools use (``__all__``): ``UpOptions`` and ``run_up(cfg, opts, stop_requested)``.
"""

from services.tools.launcher.up import UpOptions, run_up

__all__ = ["UpOptions", "run_up"]
