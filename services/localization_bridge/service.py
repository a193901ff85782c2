"""The localization bridge service: ``vehicle/pose``, ``vehicle/imu``, ``vehicle/odom`` in,
``state`` out (one State per pose, published as soon as the pose arrives, by a worker
thread blocked on the pose channel). Tuning: ``[localization]``.

A State of its own that fails validation is not sent: it is counted in ``bus.faults`` and
reported on ``events/log`` (the service base's ``DropReporter``), and the next pose is
relayed as usual."""

from __future__ import annotations

import argparse
import threading

from services.localization_bridge.fusion import StateAssembler
from shared.bus import Bus
from shared.config import RacestackConfig
from shared.config.localization import LocalizationSettings
from shared.keys import EVENTS_LOG, IMU, ODOM, POSE, STATE
from shared.messages import Imu, LogEvent, Odom, Pose, State
from shared.service import Service, publishes, subscribes


class BridgeService(Service):
    """A worker turns each pose into a state at once; IMU and odometry only update the core
    (on Zenoh's threads); the main thread is the base's watchdog (reports)."""

    NAME = "localization_bridge"
    PORTS = (
        subscribes(POSE, Pose),
        subscribes(ODOM, Odom),
        subscribes(IMU, Imu),
        publishes(STATE, State),
        publishes(EVENTS_LOG, LogEvent),
    )

    def __init__(self, bus: Bus, settings: LocalizationSettings) -> None:
        super().__init__(bus, period_s=settings.check_period_s)
        self.core = StateAssembler.from_settings(settings)
        self.state_pub = self.publisher(STATE)
        self.poses = self.subscribe_channel(POSE, capacity=settings.pose_queue)
        self.subscribe(ODOM, self.core.on_odom)
        self.subscribe(IMU, self.core.on_imu)

    @classmethod
    def create(cls, cfg: RacestackConfig, args: argparse.Namespace, bus: Bus) -> BridgeService:
        """The bridge with the ``[localization]`` settings."""
        return cls(bus, cfg.localization)

    def relay(self) -> None:
        """The worker loop: one State per pose, until the bus closes."""
        first = True
        state_key = self.state_pub.key
        while (pose := self.poses.recv()) is not None:
            with self.bus.faults.guard(state_key):  # counted and reported, never raised
                self.state_pub.put(self.core.on_pose(pose, self.wall_clock()))
            if first:
                self.log.info("first pose received; publishing %s", state_key)
                first = False

    def serve(self, stop: threading.Event) -> int:
        """Start the relay worker, then watch until `stop`."""
        self.start_worker("bridge-poses", self.relay, stop, fault_key=self.state_pub.key)
        self.log.info("ready; waiting for %s", self.poses.key)
        return super().serve(stop)


main = BridgeService.main
