"""The localization bridge service: ``vehicle/pose``, ``vehicle/imu``, ``vehicle/odom`` in,
``state`` out (one State per pose, published as soon as the pose arrives)."""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Sequence

from services.localization_bridge.fusion import StateAssembler
from shared.bus import Bus, DropReporter
from shared.config import RacestackConfig
from shared.messages import Imu, Odom, Pose, State
from shared.service_shell import run_service

log = logging.getLogger(__name__)
SERVICE = "localization_bridge"


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """The service body: wait for poses, publish states; IMU/odom only update the core."""
    core = StateAssembler()
    with Bus(cfg.bus, SERVICE) as bus:
        state_pub = bus.publisher(bus.keys.state, State)
        poses = bus.subscribe(bus.keys.pose, Pose)
        bus.subscribe(bus.keys.odom, Odom, callback=core.on_odom)
        bus.subscribe(bus.keys.imu, Imu, callback=core.on_imu)
        drops = DropReporter(bus, SERVICE)
        log.info("ready; waiting for %s", bus.keys.pose)
        got_first = False
        while not stop.is_set():
            drops.poll()
            pose = poses.wait(timeout_s=0.2)
            if pose is None:
                continue
            if not got_first:
                log.info("first pose received; publishing %s", bus.keys.state)
                got_first = True
            state_pub.put(core.on_pose(pose, time.time()))
        log.info("stopping")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.localization_bridge``."""
    return run_service(SERVICE, argv, run, description=__doc__.splitlines()[0])
