"""The localization bridge service: pose (or lidar scan), IMU and odometry in; state out.

``vehicle/pose`` (or ``vehicle/scan`` with its own lidar particle filter), ``vehicle/imu``,
``vehicle/odom`` in; ``state`` out. Tuning: ``[localization]``.

When ``state`` goes out (``[localization] state_output``):

- ``"on_pose"`` (default, event-driven): the moment a pose (or the lidar's pose) is fused,
  from the input worker itself, so the planner, which solves on a new state, starts from
  the newest pose without waiting for a clock. While no pose has been fused for
  ``fallback_after_s`` (poses stopped, all gated), the output worker publishes the estimate
  predicted to now every ``1 / publish_rate_hz`` instead (telemetry and the planner's
  age check keep seeing the localisation age; ``valid`` turns False after
  ``invalid_after_s``);
- ``"fixed_rate"``: the estimate predicted to now every ``1 / publish_rate_hz`` (the old
  bridge; the commands then answer a pose up to a period older).

Threads: odometry and IMU update the core on Zenoh's threads; a worker blocks on the pose
channel (``pose_source = "external"``) or the scan channel (``"lidar"``: scan -> particle
filter -> its pose and covariance into the EKF) and publishes the state of each fused pose;
a second worker publishes the fixed-rate or fallback state. One lock guards the core. The
``State``:

- ``source_stamp_s`` is the stamp of the newest pose the filter applied, so its age
  (``stamp_s - source_stamp_s``) is the age of the newest pose used and the planner's
  staleness check keeps judging the localisation, not the IMU;
- nothing is published before the first pose; ``valid`` is False once the newest pose is
  older than ``invalid_after_s`` (the planner brakes); degraded (older than
  ``degraded_after_s``) and the filter's rejections (future / stale stamps, gated poses,
  dropped scans) are said on ``events/log`` (rate-limited, with counts).

A ``vehicle/teleport`` (the simulator's reset or off-track marshal, or an operator placing
the car) re-initialises the filter at once at the announced pose (``FusedEstimator.teleport``;
with the lidar, the particle filter too, on the scan worker before its next scan), so the
next ``state`` is at the new pose instead of the gate holding the old one; readings stamped
at or before the teleport are dropped (counted, not reported as rejections).

Opponents (``[localization.opponents]``, on by default in a race of several cars): every
``vehicle/scan`` that arrives also goes, on a worker of its own (a one-slot channel: a scan
that waits is replaced by the newer one, never queued; with ``pose_source = "lidar"`` on the
scan worker, after the state of that scan went out), through the opponent detector and
tracker (``opponent_feed.OpponentFeed``) with the fused state moved back to the scan's
stamp; each
scan gives one ``opponents`` record (the confirmed tracks; an empty list when none). No
scan, no record. Scans while the state is not valid, or further than ``max_pose_age_s``
from it, are counted and skipped; a teleport forgets the tracks. Its cost per scan (CPU
time, median and p99) is in the stopping line and ``opponent_stats()``.

With ``filter = "passthrough"`` the newest pose is predicted to now by a unicycle
(``fusion.StateAssembler``), on the same schedule. A State of its own that fails
validation is not sent: it is counted in ``bus.faults`` and reported on ``events/log``."""

from __future__ import annotations

import argparse
import math
import threading
from collections import Counter, deque

import numpy as np

from services.localization_bridge.estimator import Estimate, FusedEstimator, Verdict
from services.localization_bridge.fusion import StateAssembler
from services.localization_bridge.lidar_pose import LidarPoseSource, start_pose
from services.localization_bridge.opponent_feed import OpponentFeed, pose_at
from shared.bus import Bus, ChannelSubscription
from shared.config import RacestackConfig
from shared.config.localization import LocalizationSettings
from shared.keys import EVENTS_LOG, IMU, ODOM, OPPONENTS, POSE, SCAN, STATE, TELEPORT
from shared.messages import (
    Imu,
    LogEvent,
    LogLevelName,
    Odom,
    Opponents,
    Pose,
    Scan,
    State,
    Teleport,
)
from shared.messages.records import MAX_POS_M, MAX_SPEED_MPS, MAX_STEER_RAD, MAX_YAW_RATE_RADPS
from shared.service import Service, publishes, subscribes
from shared.track import Track, load_track, occupancy_for


def state_record(est: Estimate, stamp_s: float) -> State:
    """The ``state`` record of an estimate, clipped into the contract's limits."""

    def clip(v: float, lim: float) -> float:
        return min(max(v, -lim), lim)

    return State(
        stamp_s=stamp_s,
        x_m=clip(est.x_m, MAX_POS_M),
        y_m=clip(est.y_m, MAX_POS_M),
        yaw_rad=est.yaw_rad,
        speed_mps=clip(est.speed_mps, MAX_SPEED_MPS),
        yaw_rate_radps=clip(est.yaw_rate_radps, MAX_YAW_RATE_RADPS),
        steering_rad=clip(est.steering_rad, MAX_STEER_RAD),
        source_stamp_s=est.pose_stamp_s if est.pose_stamp_s is not None else 0.0,
        valid=est.valid,
    )


#: The verdicts of a pose that moved the estimate (a state goes out at once, ``on_pose``).
FUSED = frozenset({Verdict.APPLIED, Verdict.INITIALISED, Verdict.REINIT})


class BridgeService(Service):
    """Inputs into the core on arrival; ``state`` on each fused pose or at a fixed rate
    (module docstring)."""

    NAME = "localization_bridge"
    PORTS = (
        subscribes(POSE, Pose),
        subscribes(SCAN, Scan),  # only with pose_source = "lidar"
        subscribes(ODOM, Odom),
        subscribes(IMU, Imu),
        subscribes(TELEPORT, Teleport),
        publishes(STATE, State),
        publishes(OPPONENTS, Opponents),
        publishes(EVENTS_LOG, LogEvent),
    )
    #: Costs of the newest this many scans are kept for the opponents' statistics.
    OPPONENT_COSTS_KEPT = 2000

    def __init__(
        self, bus: Bus, settings: LocalizationSettings, track: Track | None = None
    ) -> None:
        super().__init__(bus, period_s=settings.check_period_s)
        self.settings = settings
        self.core = FusedEstimator(settings)
        self.passthrough = StateAssembler.from_settings(settings)
        self.newest_pose: Pose | None = None
        self.lidar: LidarPoseSource | None = None
        self._lock = threading.Lock()
        self.state_pub = self.publisher(STATE)
        self.published = 0
        self.on_pose_output = settings.state_output == "on_pose"
        self._last_fused = -math.inf  #: monotonic time of the newest fused pose's state [s]
        #: one publisher at a time, and the stamp of the newest state sent [s]: the pose path
        #: and the fallback worker both publish, so a state computed before the other's but
        #: sent after it is older than what the planner already has (dropped and counted)
        self._put_lock = threading.Lock()
        self._last_put_stamp_s = -math.inf
        self.out_of_order = 0
        self._said: Counter[str] = Counter()
        self._quality = "none"
        self._place: Teleport | None = None  #: a teleport for the lidar's filter (scan worker)
        if settings.pose_source == "lidar":
            if track is None:
                raise ValueError("pose_source = 'lidar' needs the track (its occupancy map)")
            start = start_pose(track, settings) if settings.init == "start" else None
            self.lidar = LidarPoseSource(occupancy_for(track), settings, start)
            self.inputs = self.subscribe_channel(SCAN, capacity=1)
        else:
            self.inputs = self.subscribe_channel(POSE, capacity=settings.pose_queue)
        self.subscribe(ODOM, self.on_odom)
        self.subscribe(IMU, self.on_imu)
        self.subscribe(TELEPORT, self.on_teleport)
        #: opponents from the scans ([localization.opponents]; needs the track's map)
        #: built at the first scan (the map's raster is not on the start-up path)
        self.opponents: OpponentFeed | None = None
        self.opponent_counts: Counter[str] = Counter()
        self.opponent_costs_s: deque[float] = deque(maxlen=self.OPPONENT_COSTS_KEPT)
        self._forget_opponents = False
        self._opponent_track = track if settings.opponents.enabled else None
        self.opponents_enabled = self._opponent_track is not None
        self.opponent_scans: ChannelSubscription[Scan] | None = None
        if self.opponents_enabled:
            self.opponent_pub = self.publisher(OPPONENTS)
            #: with the lidar the scan worker does them after the state (one scan channel)
            self.opponent_scans = (
                self.subscribe_channel(SCAN, capacity=1) if self.lidar is None else None
            )

    @classmethod
    def create(cls, cfg: RacestackConfig, args: argparse.Namespace, bus: Bus) -> BridgeService:
        """The bridge with the ``[localization]`` settings (and the track for the lidar)."""
        loc = cfg.localization
        if loc.opponents.enabled is None:  # auto: only in a race of several cars
            several = len(cfg.cars) > 1
            loc = loc.model_copy(
                update={"opponents": loc.opponents.model_copy(update={"enabled": several})})
        needs_map = loc.pose_source == "lidar" or bool(loc.opponents.enabled)
        track = load_track(cfg.track.source) if needs_map else None
        return cls(bus, loc, track)

    # -- inputs --------------------------------------------------------------------------
    def on_odom(self, msg: Odom) -> None:
        """Wheel odometry into the filter (and the lidar's motion model)."""
        now = self.wall_clock()
        with self._lock:
            self.passthrough.on_odom(msg)
            self.core.odom(msg.stamp_s, msg.speed_mps, msg.steering_rad, msg.yaw_rate_radps, now)
            if self.lidar is not None:
                self.lidar.odom(msg.speed_mps, msg.yaw_rate_radps)

    def on_imu(self, msg: Imu) -> None:
        """A gyro sample into the filter (and the lidar's motion model)."""
        now = self.wall_clock()
        with self._lock:
            self.passthrough.on_imu(msg)
            self.core.imu(msg.stamp_s, msg.yaw_rate_radps, now)
            if self.lidar is not None:
                self.lidar.imu(msg.yaw_rate_radps)

    def on_pose(self, pose: Pose, output: bool = True) -> None:
        """An external pose into the filter; with ``state_output = "on_pose"`` the state it
        gives goes out at once (`output` False: fused only, a newer pose is queued)."""
        now = self.wall_clock()
        with self._lock:
            teleported = self.core.teleport_stamp_s
            fresh = teleported is None or pose.stamp_s > teleported
            if fresh:
                self.newest_pose = pose
            verdict = self.core.pose(pose.stamp_s, pose.x_m, pose.y_m, pose.yaw_rad, pose.cov,
                                     now)
            if not (self.on_pose_output and output):
                return
            if self.settings.filter == "passthrough":
                state = self.passthrough.on_pose(pose, now) if fresh else None
            else:
                state = self._fused_state(verdict, now)
        if state is not None:
            self._put(state, fused=True)

    def on_teleport(self, msg: Teleport) -> None:
        """The car was put elsewhere: the filter starts again at the announced pose."""
        now = self.wall_clock()
        with self._lock:
            verdict = self.core.teleport(msg.stamp_s, msg.x_m, msg.y_m, msg.yaw_rad,
                                         msg.speed_mps, now)
            if verdict is not Verdict.TELEPORT:
                return
            self.newest_pose = Pose(stamp_s=msg.stamp_s, x_m=msg.x_m, y_m=msg.y_m,
                                    yaw_rad=msg.yaw_rad)
            if self.lidar is not None:
                self._place = msg
            self._forget_opponents = True
            state = self._now_state(now) if self.on_pose_output else None
        if state is not None:  # the car is there now: say so at once
            self._put(state, fused=True)
        self.say(LogLevelName.INFO, f"teleport: state re-initialised at ({msg.x_m:.2f}, "
                 f"{msg.y_m:.2f}) m, {msg.yaw_rad:.2f} rad", limit="teleport")

    def on_scan(self, scan: Scan) -> None:
        """A scan through the particle filter; its pose into the EKF."""
        assert self.lidar is not None
        with self._lock:
            place, self._place = self._place, None
            if place is not None:
                self.lidar.place(place.stamp_s, place.x_m, place.y_m, place.yaw_rad,
                                 place.speed_mps)
            bias = self.core.estimate(self.wall_clock()).bias_radps
            motion = self.lidar.motion()
        got = self.lidar.scan(scan, bias, motion)  # the filter's update, outside the lock
        if got is None:
            if self.opponents_enabled:
                self.on_scan_opponents(scan)
            return
        e = got.estimate
        now = self.wall_clock()
        with self._lock:
            verdict = self.core.pose(got.t_s, e.x_m, e.y_m, e.yaw_rad, e.cov, now)
            state = self._fused_state(verdict, now) if self.on_pose_output else None
        if state is not None:
            self._put(state, fused=True)

    def on_scan_opponents(self, scan: Scan) -> Opponents | None:
        """One scan through the opponent detector and tracker; its ``opponents`` record
        (None: skipped, counted in ``opponent_counts``). The first call builds the
        detector on the track's map."""
        if self.opponents is None:
            track = self._opponent_track
            assert track is not None
            grid = self.lidar.pf.grid if self.lidar is not None else occupancy_for(track)
            self.opponents = OpponentFeed(grid, track, self.settings.opponents,
                                          self.settings.particle_filter)
        now = self.wall_clock()
        with self._lock:
            forget, self._forget_opponents = self._forget_opponents, False
            ready = self.core.initialised or self.newest_pose is not None
            state = self._now_state(now) if ready else None
        if forget:
            self.opponents.reset()
        if state is None or not state.valid:
            self.opponent_counts["scans_without_pose"] += 1
            return None
        dt = scan.stamp_s - state.stamp_s
        if abs(dt) > self.settings.opponents.max_pose_age_s:
            self.opponent_counts["scans_far_from_pose"] += 1
            return None
        pose = pose_at(state.x_m, state.y_m, state.yaw_rad, state.speed_mps,
                       state.yaw_rate_radps, dt)
        res = self.opponents.process(scan.stamp_s, scan.ranges_m, scan.angle_min_rad,
                                     scan.angle_increment_rad, pose)
        self.opponent_costs_s.append(res.cost_s)
        self.opponent_counts["scans"] += 1
        self.opponent_counts["detections"] += res.detections
        msg = self.opponent_pub.try_put(stamp_s=max(self.wall_clock(), scan.stamp_s),
                                        source_stamp_s=scan.stamp_s, tracks=res.tracks)
        return msg

    def opponents_loop(self) -> None:
        """The opponents worker: every scan as it arrives, until the bus closes."""
        assert self.opponent_scans is not None
        first = True
        while (scan := self.opponent_scans.recv()) is not None:
            self.on_scan_opponents(scan)
            if first:
                self.log.info("first scan for the opponents on %s", self.opponent_scans.key)
                first = False

    def opponent_stats(self) -> dict[str, float]:
        """Scans processed, detections, skipped scans and the cost per scan [ms] (CPU
        time of detector and tracker: median, p99 over the newest ``OPPONENT_COSTS_KEPT``)."""
        out: dict[str, float] = dict(self.opponent_counts)
        costs = np.asarray(self.opponent_costs_s, dtype=float) * 1e3
        if costs.size:
            out["cost_median_ms"] = float(np.median(costs))
            out["cost_p99_ms"] = float(np.percentile(costs, 99))
        return out

    def _fused_state(self, verdict: Verdict, now: float) -> State | None:
        """The state of a pose the filter just fused at `now` (None: it was not fused).
        Called holding the lock; the quality check is the fallback's (it says lines)."""
        if verdict not in FUSED:
            return None
        return state_record(self.core.estimate(now), now)

    def _now_state(self, now: float) -> State:
        """The state at `now` after a teleport (holding the lock): the filter's, or with
        ``filter = "passthrough"`` the announced pose's."""
        if self.settings.filter == "passthrough" and self.newest_pose is not None:
            return self.passthrough.on_pose(self.newest_pose, now)
        return state_record(self.core.estimate(now), now)

    def _put(self, state: State, fused: bool = False) -> None:
        """Publish one state (`fused`: of a pose just fused), unless it is not newer than the
        last one sent (``out_of_order``); a fault is counted and reported, never raised."""
        with self._put_lock, self.bus.faults.guard(self.state_pub.key):
            if fused:
                self._last_fused = self.clock()
            if state.stamp_s <= self._last_put_stamp_s:
                self.out_of_order += 1  # the other thread sent a newer state meanwhile
                return
            self._last_put_stamp_s = state.stamp_s
            self.state_pub.put(state)
            self.published += 1

    def receive(self) -> None:
        """The input worker: every pose (or scan) as it arrives, until the bus closes.

        Poses queued behind the one received (the worker was late: ``pose_queue`` > 1) are
        all fused, in order, and only the newest one's state goes out: every valid pose
        reaches the filter, and the planner is not handed an older state first."""
        first = True
        while (msg := self.inputs.recv()) is not None:
            if self.lidar is not None:
                self.on_scan(msg)
            else:
                while (newer := self.inputs.try_recv()) is not None:
                    self.on_pose(msg, output=False)
                    msg = newer
                self.on_pose(msg)
            if first:
                self.log.info("first input on %s", self.inputs.key)
                first = False

    # -- output --------------------------------------------------------------------------
    def current_state(self) -> State:
        """The state now (wall clock)."""
        now = self.wall_clock()
        with self._lock:
            if self.settings.filter == "passthrough":
                if self.newest_pose is None:
                    return State(stamp_s=now, x_m=0.0, y_m=0.0, yaw_rad=0.0, speed_mps=0.0,
                                 yaw_rate_radps=0.0, steering_rad=0.0, source_stamp_s=0.0,
                                 valid=False)
                return self.passthrough.on_pose(self.newest_pose, now)
            est = self.core.estimate(now)
        self._say_quality(est)
        return state_record(est, now)

    def started(self) -> bool:
        """Whether a pose has arrived: before it nothing is published (the planner's own
        watchdog brakes on the silence, as it always did)."""
        with self._lock:
            return self.core.initialised or self.newest_pose is not None

    def publish_loop(self, stop: threading.Event) -> None:
        """The output worker, until `stop`, from the first pose on: one State every
        ``1 / publish_rate_hz``; with ``state_output = "on_pose"`` only while no state has
        gone out for ``fallback_after_s`` (then it sleeps until that could be so, and the
        fused states' quality is judged here only while it is not "ok")."""
        period = 1.0 / self.settings.publish_rate_hz
        quiet_s = self.settings.fallback_after_s
        next_t = self.clock()
        while not stop.is_set():
            now = self.clock()
            quiet = not self.on_pose_output or now - self._last_fused >= quiet_s
            if self.started() and (quiet or self._quality != "ok"):
                state = self.current_state()  # also says a change of quality
                if quiet:
                    self._put(state)
            next_t += period
            if not quiet:  # the poses drive the output: look again when they might not
                next_t = max(next_t, self._last_fused + quiet_s)
            wait = next_t - self.clock()
            if wait < -period:  # far behind (a stalled machine): realign, no burst
                next_t, wait = self.clock(), 0.0
            if wait > 0.0 and stop.wait(wait):
                break

    def _say_quality(self, est: Estimate) -> None:
        q = "invalid" if not est.valid else "degraded" if est.degraded else "ok"
        if q == self._quality:
            return
        before, self._quality = self._quality, q
        age = f"{est.pose_age_s * 1e3:.0f} ms" if math.isfinite(est.pose_age_s) else "none"
        if q == "ok":
            if before != "none":
                self.say(LogLevelName.INFO, "localisation ok again", limit="quality")
        else:
            level = LogLevelName.ERROR if q == "invalid" else LogLevelName.WARNING
            self.say(level, f"localisation {q} (newest pose {age} old)", limit="quality")

    def counts(self) -> Counter[str]:
        """Every rejection so far (the filter's and the lidar's), by reason."""
        with self._lock:
            out = Counter(self.core.counts)
            if self.lidar is not None:
                out.update(self.lidar.counts)
        return out

    def tick(self) -> None:
        """The watchdog: say the rejections that grew since the last line."""
        ok = {"pose_applied", "pose_initialised", "scans_used", "teleport_applied"}
        now = self.counts()
        grown = {
            k: v - self._said[k] for k, v in now.items()
            if k not in ok and not k.endswith("_before_teleport") and v > self._said[k]
        }
        if grown and self.say(
            LogLevelName.WARNING,
            "rejected inputs: " + ", ".join(f"{k} {v}" for k, v in sorted(grown.items())),
            limit="rejections",
        ):
            self._said = now

    def serve(self, stop: threading.Event) -> int:
        """Start the input and output workers, then watch until `stop`."""
        key = self.state_pub.key
        self.start_worker("bridge-inputs", self.receive, stop, fault_key=key)
        self.start_worker("bridge-state", lambda: self.publish_loop(stop), stop, fault_key=key)
        if self.opponent_scans is not None:
            self.start_worker("bridge-opponents", self.opponents_loop, stop,
                              fault_key=self.opponent_pub.key)
        self.log.info("ready (%s pose); waiting for %s", self.settings.pose_source,
                      self.inputs.key)
        code = super().serve(stop)
        if self.opponents_enabled:
            st = self.opponent_stats()
            self.log.info(
                "opponents: %d scans, %d detections, %d without a pose, cost per scan "
                "median %.2f ms, p99 %.2f ms", st.get("scans", 0), st.get("detections", 0),
                st.get("scans_without_pose", 0) + st.get("scans_far_from_pose", 0),
                st.get("cost_median_ms", math.nan), st.get("cost_p99_ms", math.nan))
        self.log.info("stopping: %s", self.input_summary())
        return code

    def input_summary(self) -> str:
        """One line of what became of the inputs: the pose (or scan) channel's counts, when
        the bus keeps them (valid records taken, valid ones lost (overwritten, stale),
        garbage rejected), and the filter's counts by verdict."""
        stats = getattr(self.inputs, "stats", None)
        line = ""
        if stats is not None:
            st = stats()
            line = (f"{self.inputs.key}: {st.valid} valid taken, {st.dropped} valid lost "
                    f"({st.overwritten} overwritten, {st.stale} stale), {st.rejected} "
                    "rejected; ")
        counts = ", ".join(f"{k} {v}" for k, v in sorted(self.counts().items()))
        return line + f"filter: {counts or 'nothing'}"


main = BridgeService.main
