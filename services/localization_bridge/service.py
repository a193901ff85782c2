"""The localization bridge service: ``vehicle/pose``, ``vehicle/imu``, ``vehicle/odom`` in,
``state`` out (one State per pose, published as soon as the pose arrives, by a worker
thread blocked on the pose channel).

A State of its own that fails validation is not sent: it is counted in ``bus.faults`` and
reported on ``events/log`` (``DropReporter``), and the next pose is relayed as usual."""

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
from shared.service_shell import Worker, run_service

log = logging.getLogger(__name__)
SERVICE = "localization_bridge"


def run(cfg: RacestackConfig, args: argparse.Namespace, stop: threading.Event) -> int:
    """The service body: a worker turns each pose into a state at once; IMU/odom only
    update the core (on Zenoh's threads); the main thread reports drops."""
    core = StateAssembler()
    with Bus(cfg.bus, SERVICE) as bus:
        state_pub = bus.publisher(bus.keys.state, State)
        poses = bus.subscribe_channel(bus.keys.pose, Pose)
        bus.subscribe(bus.keys.odom, Odom, callback=core.on_odom)
        bus.subscribe(bus.keys.imu, Imu, callback=core.on_imu)
        drops = DropReporter(bus, SERVICE)

        def relay() -> None:
            first = True
            while (pose := poses.recv()) is not None:
                with bus.faults.guard(bus.keys.state):  # counted and reported, never raised
                    state_pub.put(core.on_pose(pose, time.time()))
                if first:
                    log.info("first pose received; publishing %s", bus.keys.state)
                    first = False

        worker = Worker(
            "bridge-poses", relay, stop, faults=bus.faults, fault_key=bus.keys.state
        ).start()
        log.info("ready; waiting for %s", bus.keys.pose)
        while not stop.wait(0.2):
            drops.poll()
        log.info("stopping")
    worker.join(timeout_s=2.0)  # the closed bus ends it; re-raises if it crashed
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m services.localization_bridge``."""
    return run_service(SERVICE, argv, run, description=__doc__.splitlines()[0])
