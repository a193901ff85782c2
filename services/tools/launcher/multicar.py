"""``racestack up --cars N`` (or a ``[[cars]]`` list of two or more): a race of several cars.

What runs: ONE simulator (it integrates every car of ``[[cars]]``, ``shared.config.cars``),
and for each car its own localization bridge and planner (and telemetry, recording into
``RUN/<car>/``), each reading ``RUN/config.<car>.toml``: the run's configuration with
``[bus] car`` set to the car and ``[planner] method`` to the car's method. The first car's
processes keep the service names (``planner``, log ``RUN/logs/planner.log``); the others'
are named ``<service>.<car>`` (``RUN/logs/planner.car1.log``).

``cars_config`` makes the list of ``--cars N``: the configuration's ``[[cars]]`` entries
first, then ``car<i>`` with the same method, ``DEFAULT_SPEED_SCALE`` and ``DEFAULT_GAP_M``
(the default second car: the same method at 0.85 of its speed commands, 1.5 m behind).

The race: every car is reset (``sim/control`` on its keys), each drives its out lap, then
``--laps`` timed laps; the race ends when every car has them (or no lap event came for
``lap_timeout_s``). At the end: one lap table with a column per car (``format_table``:
each car's laps, mean, vs the best car), the incidents (the simulator's contact lines on
``events/log``: who hit whom, when, how deep) and each process's CPU use.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from services.tools.launcher.cpu import CpuMeter, format_cpu
from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.bus import Bus
from shared.config import RacestackConfig
from shared.config.cars import CarEntry
from shared.config.methods import METHODS
from shared.config.toml_write import dumps as toml_dumps
from shared.evaluation import LapRecord, format_table, results_document
from shared.keys import DEFAULT_CAR, Keys
from shared.messages import (
    LapEvent,
    LapKindName,
    LogEvent,
    LogLevelName,
    Plan,
    SimActionName,
    SimControl,
)
from shared.vehicle.incidents import parse_incident

#: Speed scale of the cars ``--cars N`` adds after the configured ones.
DEFAULT_SPEED_SCALE = 0.85
#: Their start gap behind the car before them [m].
DEFAULT_GAP_M = 1.5
#: The services started once for all cars (the rest: once per car).
SHARED_SERVICES = frozenset({"simulator"})

__all__ = [
    "DEFAULT_GAP_M",
    "DEFAULT_SPEED_SCALE",
    "CarRace",
    "cars_config",
    "process_name",
    "race_cars",
]


def cars_config(data: dict[str, Any], n: int) -> dict[str, Any]:
    """`data` (TOML tables) with ``[[cars]]`` of `n` cars (module docstring); ``[bus] car``
    is the first car's name."""
    out = dict(data)
    given = list(data.get("cars", []))[:n]
    first = data.get("bus", {}).get("car", DEFAULT_CAR)
    if not given:
        given = [{"name": first}]
    names = {c["name"] for c in given}
    i = 1
    while len(given) < n:
        name = f"car{i}"
        i += 1
        if name in names:
            continue
        names.add(name)
        given.append({"name": name, "speed_scale": DEFAULT_SPEED_SCALE,
                      "start_gap_m": DEFAULT_GAP_M})
    out["cars"] = given
    out["bus"] = {**data.get("bus", {}), "car": given[0]["name"]}
    return out


def process_name(service: str, car: str, first: str) -> str:
    """The process (and log) name of `service` of `car` (`first`: the first car's name)."""
    return service if car == first or service in SHARED_SERVICES else f"{service}.{car}"


def car_label(car: CarEntry, method: str) -> str:
    """A car's column in the lap table: ``car1 (cimpcc x0.85)``."""
    scale = "" if car.speed_scale == 1.0 else f" x{car.speed_scale:g}"
    pace = "" if car.pace == 1.0 else f" pace {car.pace:g}"
    return f"{car.name} ({method}{scale}{pace})"


@dataclass
class CarRace:
    """One car's side of the race: its laps, solve times and off-track events."""

    car: CarEntry
    method: str
    laps: list[LapRecord] = field(default_factory=list)
    solve_ms: list[float] = field(default_factory=list)
    started: bool = False
    off_track: int = 0
    out_lap_off_track: int = 0

    def see(self, ev: LapEvent) -> str | None:
        """Count one lap event; the line to print (None: nothing)."""
        name = self.car.name
        if ev.kind == LapKindName.START and not self.started:
            self.started = True
            return f"{name}: out lap done, timing"
        if ev.kind == LapKindName.LAP and ev.lap_time_s is not None:
            self.laps.append(LapRecord(ev.lap_time_s, ev.mean_speed_mps or 0.0,
                                       ev.off_track_events, ev.max_abs_e_con_m or 0.0))
            return (f"{name} lap {len(self.laps)}: {ev.lap_time_s:.3f} s, "
                    f"{ev.mean_speed_mps or 0.0:.2f} m/s, off-track {ev.off_track_events}")
        if ev.kind == LapKindName.OFF_TRACK:
            self.off_track += 1
            if not self.started:
                self.out_lap_off_track += 1
            return f"{name}: off track at lap {ev.lap}"
        return None


def write_car_configs(data: dict[str, Any], cfg: RacestackConfig, run_dir: Path
                      ) -> tuple[Path, dict[str, Path]]:
    """The run's configuration (``RUN/config.toml``: the simulator's and the launcher's) and
    each car's (``RUN/config.<car>.toml``)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    base = run_dir / "config.toml"
    base.write_text(toml_dumps(data, "racestack up: the configuration of the race (all cars)"),
                    encoding="utf-8")
    per_car: dict[str, Path] = {}
    for car in cfg.cars:
        own = dict(data)
        own["bus"] = {**data.get("bus", {}), "car": car.name}
        if cfg.bus.security == "mtls":  # its bridge, planner and telemetry: its own names
            own["bus"]["per_car_identity"] = True
        own["planner"] = {**data.get("planner", {}),
                          "method": car.method or cfg.planner.method}
        if car.pace != 1.0:  # its planner races that share of its line's speeds
            section = METHODS[own["planner"]["method"]].section or ""
            own["planner"][section] = {**data.get("planner", {}).get(section, {}),
                                       "speed_share": car.pace}
        path = run_dir / f"config.{car.name}.toml"
        path.write_text(toml_dumps(own, f"racestack up: car {car.name}'s configuration"),
                        encoding="utf-8")
        per_car[car.name] = path
    return base, per_car


def _alive(bus: Bus, car: str, timeout_s: float = 1.0) -> set[str]:
    """The services whose liveliness token is seen under `car`'s keys now."""
    keys = Keys(car)
    out: set[str] = set()
    try:
        for reply in bus.session.liveliness().get(keys.alive_any, timeout=timeout_s):
            ok = getattr(reply, "ok", None)
            if ok is not None:
                name = keys.service_of_alive_key(str(ok.key_expr))
                if name:
                    out.add(name)
    except Exception:  # a closing session: nothing is alive
        return out
    return out


def race_cars(
    cfg: RacestackConfig,
    opts: Any,
    bus: Bus,
    track: Any,
    run_dir: Path,
    stop_requested: Any,
    data: dict[str, Any],
) -> int:
    """Start the processes of every car, race, print the table and incidents, stop all
    (exit codes as ``up``'s: 0 all laps, 1 not all, 3 a process died or never came, 130
    interrupted)."""
    from services.tools.launcher.up import Launcher, OffTrackTally

    first = cfg.cars[0].name
    base, per_car = write_car_configs(data, cfg, run_dir)
    races = {c.name: CarRace(c, c.method or cfg.planner.method) for c in cfg.cars}
    incidents = []
    interrupted = False
    with Supervisor(log_dir=run_dir / "logs") as sup:
        node = Launcher(bus)
        node.announce()
        lap_subs = {c: bus.subscribe(Keys(c).lap, LapEvent, queue_size=1000) for c in races}
        log_subs = {c: bus.subscribe(Keys(c).events_log, LogEvent, queue_size=1000)
                    for c in races}
        for c, r in races.items():
            bus.subscribe(Keys(c).plan, Plan,
                          lambda p, r=r: r.solve_ms.append(p.solve_time_ms))
        controls = {c: bus.publisher(Keys(c).sim_control, SimControl) for c in races}
        children = {}
        wanted: dict[str, set[str]] = {c: set() for c in races}
        for name in opts.services:
            cars = [first] if name in SHARED_SERVICES else list(races)
            for car in cars:
                extra: list[str] = []
                if name == "telemetry":
                    extra = [*opts.telemetry_args, "--out", str(run_dir / car)]
                    if car != first and "--serve" in extra:  # one live viewer: the first car
                        i = extra.index("--serve")
                        del extra[i:i + 2]
                config = base if name in SHARED_SERVICES else per_car[car]
                proc = process_name(name, car, first)
                children[proc] = sup.start(proc, service_argv(name, str(config), extra))
                wanted[car].add(name)
        print(f"waiting for {', '.join(children)} ...", flush=True)

        def all_alive() -> bool:
            return all(want <= _alive(bus, car) for car, want in wanted.items())

        # every car's planner builds (or compiles) its solver at once, on the same cores
        start_timeout_s = opts.start_timeout_s * len(races)
        ok = sup.wait_until(lambda: all_alive() or stop_requested(), start_timeout_s,
                            poll_s=0.5)
        if stop_requested():
            print("interrupted", flush=True)
            return 130
        if not ok:
            for child in sup.dead():
                print(f"{child.name} (pid {child.pid}) exited with code {child.exit_code()}; "
                      f"log: {child.log_path}", flush=True)
            missing = {car: sorted(w - _alive(bus, car)) for car, w in wanted.items()}
            print(f"not all alive after {start_timeout_s:.0f} s: {missing}", flush=True)
            return 3
        print(f"all services alive: racing {len(races)} cars", flush=True)
        cpu = CpuMeter({n: c.pid for n, c in children.items()}, own="launcher (with the hub)")
        for pub in controls.values():
            pub.wait_matching(5.0)
        cpu.start()
        for pub in controls.values():
            pub.put(SimControl(stamp_s=time.time(), action=SimActionName.RESET))
        last_progress = time.monotonic()
        while any(len(r.laps) < opts.laps for r in races.values()):
            if stop_requested():
                print("interrupted: the laps finished so far, then stopping", flush=True)
                interrupted = True
                break
            if sup.dead():
                for child in sup.dead():
                    print(f"{child.name} (pid {child.pid}) exited with code "
                          f"{child.exit_code()} during the race; log: {child.log_path}",
                          flush=True)
                return 3
            for car, sub in lap_subs.items():
                for ev in sub.drain():
                    last_progress = time.monotonic()
                    line = races[car].see(ev)
                    if line:
                        print(line, flush=True)
            for car, sub in log_subs.items():
                for msg in sub.drain():
                    inc = parse_incident(msg.text) if msg.source == "simulator" else None
                    if inc is not None:
                        incidents.append(inc)
                        print(f"[simulator] {msg.text}", flush=True)
                    elif msg.level in (LogLevelName.WARNING, LogLevelName.ERROR):
                        print(f"[{car} {msg.source}] {msg.level}: {msg.text}", flush=True)
            if time.monotonic() - last_progress > opts.lap_timeout_s:
                print(f"no lap event for {opts.lap_timeout_s:.0f} s: giving up", flush=True)
                break
            time.sleep(0.05)
        runs = []
        for r in races.values():
            tally = OffTrackTally(started=r.started, total=r.off_track,
                                  out_lap=r.out_lap_off_track)
            runs.append(tally.run(car_label(r.car, r.method), r.laps, list(r.solve_ms),
                                  opts.laps, extra={"car": r.car.name}))
        print(format_table(results_document(track.name, track.length_m, runs)), flush=True)
        print(incident_table(incidents, list(races)), flush=True)
        print(format_cpu(cpu.stop()), flush=True)
        print("stopping the stack", flush=True)
    if interrupted:
        return 130
    return 0 if all(len(r.laps) >= opts.laps for r in races.values()) else 1


def incident_table(incidents: list[Any], cars: list[str]) -> str:
    """The incidents of the race: a count per car as striker, then one line each."""
    if not incidents:
        return "incidents: 0 contacts"
    lines = [f"incidents: {len(incidents)} contact{'s' if len(incidents) != 1 else ''}"]
    for car in cars:
        hit = sum(1 for i in incidents if i.striker == car)
        struck = sum(1 for i in incidents if car in i.struck.split("+"))
        lines.append(f"  {car}: hit another {hit} time{'s' if hit != 1 else ''}, "
                     f"was hit or touched {struck} time{'s' if struck != 1 else ''}")
    for i in incidents:
        who = f"{i.striker} hit {i.struck}" if i.striker != "none" else f"{i.struck} touched"
        lines.append(f"  #{i.number} t = {i.t_s:.2f} s: {who}, depth {i.depth_m * 100:.1f} cm, "
                     f"{i.closing_mps:.2f} m/s closing")
    return "\n".join(lines)
