"""``racestack up``: the stack as one process per service, supervised, racing the simulator.

What other tools use (``__all__``): ``UpOptions`` and ``run_up(cfg, opts, stop_requested)``;
``up_config`` (``--track``/``--method`` applied to the configuration) and
``console_logging`` (the launcher's quiet console: warnings and errors, ``-v`` for all).
"""

from services.tools.launcher.up import UpOptions, console_logging, run_up, up_config

__all__ = ["UpOptions", "console_logging", "run_up", "up_config"]
