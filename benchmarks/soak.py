"""Soak: race the whole stack for a long time, watch memory and every real-time miss (15, 25).

Starts ``racestack up`` (the launcher with its router, the simulator, the localization
bridge, the planner and the telemetry, one process each, as a user would) on a built-in
track with more laps than fit in the time, on its own car name and a free loopback port, so
it never meets another stack on this machine, and its simulated lidar at ``--lidar-hz``
(default 10 Hz; 40 Hz with ``--pose-source lidar``, the particle filter's rate). Every
``--sample-s`` it reads, with psutil, the resident set size of each process the launcher
started (found as its children by their ``-m services.<name>`` command line) and of the
launcher itself, and the size of the recording's segments on disk. After ``--minutes`` it
stops the stack with SIGINT (the launcher stops its children; the recording closes its last
segment) and prints:

* per process: RSS at ``--warmup-min`` (5 min), at the end (each the largest sample of one
  segment length: the telemetry's RSS is a saw-tooth, rising within a segment and falling
  when it closes), the largest, and the growth from the warm-up to the end [%] (the
  acceptance: <= 10 % for every process);
* the recording: total size, segments, and its growth per minute after the warm-up
  (least-squares slope of size over time) [MB/min];
* that every closed segment verifies (``rerun rrd verify``), with the count;
* the real-time misses of issue 25, read from the services' logs (``RUN/logs/*.log``):
  stale-state brakes of the planner (its "stale or invalid state (age N ms): braking" lines,
  one per braking episode, with their ages), "localisation invalid" reports of the bridge
  (rate-limited by the bridge to one line per ``EVENT_INTERVAL_S``: a lower bound), the
  simulator's slowdowns of its world (its closing line: count, seconds, longest, the
  world's rate; an older simulator's skips ahead), off-track events
  (the simulator's "off track at s = ..." lines), the laps, and ``pf_lost`` of the lidar
  filter; then one PASS/FAIL line per acceptance figure: 0 stale brakes, 0 off-track, 0
  skips (a slowdown counts as one: it is the same lost real time), flat memory (growth
  <= 10 %).

Options of issue 25's acceptance runs:

* ``--hog``: a busy loop pinned to the last CPU (``benchmarks/hog.py``, as
  ``benchmarks/stack_latency.py``), started by PID once the stack races and stopped by PID
  at the end;
* ``--pose-source lidar``: ``[localization] pose_source = "lidar"`` (the bridge's particle
  filter on the simulated scans; ``--track`` then needs an occupancy map, e.g. map416);
* ``--viewer``: ``up --serve PORT`` and a headless Rerun viewer (``rerun --headless``,
  ``benchmarks/telemetry_load.HeadlessViewer``) connected to it; its time cursor's lag
  behind the wall clock is sampled once a second and printed (median / p99 / max). Where
  the viewer cannot start headless (no Vulkan driver) the soak says so and stops.

    .venv/bin/python -m benchmarks.soak --minutes 30 --hog         # the acceptance run
    .venv/bin/python -m benchmarks.soak --minutes 10 --hog --pose-source lidar \
        --track ../shared/tracks/map416
    .venv/bin/python -m benchmarks.soak --minutes 5 --hog --viewer
    .venv/bin/python -m benchmarks.soak --minutes 2 --warmup-min 0.5   # a quick look

The samples and counts are written to ``<out>/soak.json`` (``--out``, default a temp folder).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from benchmarks.hog import hog_cpu, load_average, start_hog
from services.telemetry.rrd_files import find_segments
from services.tools.launcher.supervisor import stop_process
from shared.net import free_loopback_port

ROOT = Path(__file__).resolve().parents[1]
#: Processes watched: the launcher and the services it starts.
WATCHED = ("launcher", "simulator", "localization_bridge", "planner", "telemetry")
#: Largest allowed RSS growth after the warm-up [%] (issue 15).
GROWTH_LIMIT_PCT = 10.0
MB = 1e6
#: A completed lap in the launcher's output: ``lap 3: 13.270 s, ...``.
LAP_LINE = re.compile(r"^lap \d+: [\d.]+ s", re.MULTILINE)
#: The planner's stale-state brake (one line per braking episode).
STALE_LINE = re.compile(r"stale or invalid state \(age (\d+) ms\): braking")
#: The bridge's "localisation invalid" report.
INVALID_LINE = re.compile(r"localisation invalid")
#: The simulator's off-track report.
OFF_TRACK_LINE = re.compile(r"off track at s = ")
#: The simulator's closing line: its slowdowns of the world and the world's rate.
SIM_CLOSE_LINE = re.compile(
    r"stopping \((\d+) real-time overruns, (\d+) slowdowns of the world \(([\d.]+) s, "
    r"longest ([\d.]+) s; the world ran at ([\d.]+) of real time\)")
#: The same of a simulator before issue 25's change (it skipped ahead instead).
OLD_SIM_CLOSE_LINE = re.compile(r"stopping \((\d+) real-time overruns, (\d+) skips ahead "
                                r"\(([\d.]+) s\)")
#: An increment of the bridge's rejection counts: ``pf_lost 3``.
PF_LOST = re.compile(r"rejected inputs: .*?\bpf_lost (\d+)")


def _toml_value(v: Any) -> str:
    """`v` (str, bool, int, float or a list of them) as a TOML value."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string for these
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} into the soak's TOML")


def _toml_tables(table: dict[str, Any], prefix: str = "") -> str:
    """`table` (nested dicts of values) as TOML tables, a header per dict with values."""
    values = {k: v for k, v in table.items() if not isinstance(v, dict)}
    text = ""
    if values and prefix:
        text += f"[{prefix}]\n" + "".join(f"{k} = {_toml_value(v)}\n"
                                           for k, v in values.items()) + "\n"
    for k, v in table.items():
        if isinstance(v, dict):
            text += _toml_tables(v, f"{prefix}.{k}" if prefix else k)
    return text


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    """`base` with `extra` laid over it, table by table (`extra`'s values win)."""
    out = dict(base)
    for k, v in extra.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) \
            else v
    return out


def soak_config(
    path: Path, port: int, track: str, segment_s: float, lidar_hz: float,
    pose_source: str = "external", extra: str = "",
) -> Path:
    """A TOML of the soak: its own car name and hub port, the track, the segment length,
    the simulated lidar's rate [Hz], the bridge's pose source, with `extra` (TOML) laid over
    it table by table (so ``[telemetry]`` in `extra` adds to the soak's own ``[telemetry]``).

    Raises:
        ValueError: `extra` is not valid TOML.
    """
    base: dict[str, Any] = {
        "track": {"source": track},
        "bus": {"car": f"soak{port}", "listen": [f"tcp/127.0.0.1:{port}"]},
        "telemetry": {"segment_interval_s": segment_s},
        "localization": {"pose_source": pose_source},
        "simulator": {"lidar": {"rate_hz": lidar_hz}},
    }
    try:
        over = tomllib.loads(extra)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"--config-extra is not valid TOML: {e}") from None
    path.write_text(_toml_tables(_merge(base, over)), encoding="utf-8")
    return path


def misses(logs: dict[str, str], up_log: str) -> dict[str, Any]:
    """The real-time misses of a race from the services' logs (name -> text) and the
    launcher's output: stale brakes (count, ages [ms]), localisation-invalid reports,
    simulator overruns / skips / slowdowns (with seconds; None without its closing line),
    off-track events, laps and pf_lost."""
    ages = [int(a) for a in STALE_LINE.findall(logs.get("planner", ""))]
    sim = logs.get("simulator", "")
    close = SIM_CLOSE_LINE.findall(sim)
    out: dict[str, Any] = {
        "stale_brakes": len(ages), "stale_ages_ms": ages,
        "localisation_invalid": len(INVALID_LINE.findall(logs.get("localization_bridge", ""))),
        "off_track": len(OFF_TRACK_LINE.findall(sim)),
        "laps": len(LAP_LINE.findall(up_log)),
        "pf_lost": sum(int(n) for n in PF_LOST.findall(logs.get("localization_bridge", ""))),
        "overruns": None, "skips": None, "skipped_s": None, "slowdowns": None,
        "slowed_s": None, "longest_slowdown_s": None, "world_rate": None,
    }
    if close:
        over, slow, slowed, longest, rate = close[-1]
        out.update(overruns=int(over), skips=0, skipped_s=0.0, slowdowns=int(slow),
                   slowed_s=float(slowed), longest_slowdown_s=float(longest),
                   world_rate=float(rate))
    elif old := OLD_SIM_CLOSE_LINE.findall(sim):
        over, skips, skipped = old[-1]
        out.update(overruns=int(over), skips=int(skips), skipped_s=float(skipped),
                   slowdowns=0, slowed_s=0.0)
    return out


def read_logs(log_dir: Path) -> dict[str, str]:
    """Each service's log in `log_dir` (``<name>.log``) as text, by name."""
    if not log_dir.is_dir():
        return {}
    return {f.stem: f.read_text(errors="replace") for f in sorted(log_dir.glob("*.log"))}


def verdicts(m: dict[str, Any], worst_growth_pct: float, memory_ok: bool) -> list[str]:
    """One PASS/FAIL line per acceptance figure of issue 25."""
    def line(name: str, ok: bool, got: str) -> str:
        return f"{'PASS' if ok else 'FAIL'}  {name}: {got}"
    skips = None if m["skips"] is None else m["skips"] + m["slowdowns"]
    return [
        line("0 stale-state brakes", m["stale_brakes"] == 0, f"{m['stale_brakes']}"),
        line("0 off-track", m["off_track"] == 0, f"{m['off_track']}"),
        line("0 simulator skips or slowdowns of its world", skips == 0,
             "no closing line of the simulator" if skips is None
             else f"{m['skips']} skips, {m['slowdowns']} slowdowns"),
        line("flat memory (growth <= 10 %)", memory_ok, f"largest {worst_growth_pct:.1f} %"),
    ]


def service_of(proc: psutil.Process) -> str | None:
    """The racestack service a child process runs (``-m services.<name>``), or None."""
    try:
        cmd = proc.cmdline()
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return None
    for i, arg in enumerate(cmd[:-1]):
        if arg == "-m" and cmd[i + 1].startswith("services."):
            return cmd[i + 1].split(".")[1]
    return None


def rss_by_service(launcher: psutil.Process) -> dict[str, float]:
    """RSS [MB] of the launcher and of each service process it started."""
    out: dict[str, float] = {}
    try:
        out["launcher"] = launcher.memory_info().rss / MB
        children = launcher.children(recursive=True)
    except psutil.NoSuchProcess:
        return out
    for child in children:
        name = service_of(child)
        if name is None:
            continue
        try:
            out[name] = child.memory_info().rss / MB
        except psutil.NoSuchProcess:
            continue
    return out


def recording_bytes(run_dir: Path) -> tuple[int, int]:
    """(total bytes, number of segments) of the run's recording so far."""
    try:
        files = find_segments(run_dir)
    except FileNotFoundError:
        return 0, 0
    return sum(f.stat().st_size for f in files if f.exists()), len(files)


def verify(files: list[Path], env: dict[str, str]) -> tuple[int, list[str]]:
    """(segments that pass ``rerun rrd verify``, the messages of those that do not)."""
    rerun = str(Path(sys.executable).parent / "rerun")
    ok, bad = 0, []
    for f in files:
        res = subprocess.run([rerun, "rrd", "verify", str(f)], env=env, capture_output=True,
                             text=True, timeout=300)
        if res.returncode == 0:
            ok += 1
        else:
            bad.append(f"{f.name}: {(res.stderr or res.stdout).strip()[-300:]}")
    return ok, bad


def growth_table(
    samples: list[dict[str, Any]], warmup_s: float, window_s: float
) -> list[dict[str, Any]]:
    """Per process: RSS after the warm-up and at the end, max, growth [%].

    "After the warm-up" and "at the end" are each the LARGEST sample of a window of
    `window_s` (one recording segment: the telemetry's RSS rises within a segment and falls
    when it closes, so single samples would depend on where in that saw-tooth they fall).
    """
    after = [s for s in samples if s["t_s"] >= warmup_s]
    if not after:
        return []
    t_end = after[-1]["t_s"]
    first = [s for s in after if s["t_s"] < warmup_s + window_s]
    last = [s for s in after if s["t_s"] > t_end - window_s]
    rows = []
    for name in WATCHED:
        a_all = [s["rss_mb"][name] for s in first if name in s["rss_mb"]]
        b_all = [s["rss_mb"][name] for s in last if name in s["rss_mb"]]
        if not a_all or not b_all:
            continue
        a, b = max(a_all), max(b_all)
        peak = max(s["rss_mb"].get(name, 0.0) for s in after)
        rows.append({"service": name, "rss_warm_mb": a, "rss_end_mb": b, "rss_max_mb": peak,
                     "growth_pct": 100.0 * (b - a) / a})
    return rows


def slope_mb_per_min(samples: list[dict[str, Any]], warmup_s: float) -> float:
    """Least-squares growth of the recording after the warm-up [MB/min]."""
    pts = [(s["t_s"], s["rrd_bytes"]) for s in samples if s["t_s"] >= warmup_s]
    if len(pts) < 2:
        return float("nan")
    t, b = np.array(pts, dtype=float).T
    return float(np.polyfit(t / 60.0, b / MB, 1)[0])


def run(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="racestack-soak-"))
    out.mkdir(parents=True, exist_ok=True)
    port = free_loopback_port()
    lidar_hz = args.lidar_hz or (40.0 if args.pose_source == "lidar" else 10.0)
    try:
        toml = soak_config(out / "soak.toml", port, args.track, args.segment_s, lidar_hz,
                           args.pose_source, args.config_extra.replace("\\n", "\n"))
    except ValueError as e:
        print(f"soak: {e}", file=sys.stderr)
        return 2
    run_dir = out / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    for name in ("XDG_CONFIG_HOME", "XDG_DATA_HOME"):  # rerun's analytics stay off and here
        (out / name).mkdir(exist_ok=True)
        env[name] = str(out / name)
    subprocess.run([str(Path(sys.executable).parent / "rerun"), "analytics", "disable"],
                   env=env, capture_output=True, timeout=60)
    log_path = out / "up.log"
    cmd = [sys.executable, "-m", "services.tools.cli", "up", "--config", str(toml),
           "--laps", str(args.laps), "--run-dir", str(run_dir)]
    serve = free_loopback_port() if args.viewer else None
    if serve is not None:
        cmd += ["--serve", str(serve)]
    print(f"soak: {args.minutes:g} min on {args.track}, pose source {args.pose_source}, "
          f"lidar {lidar_hz:g} Hz, hog {'on' if args.hog else 'off'}, viewer "
          f"{'on' if args.viewer else 'off'}; {' '.join(cmd)}; log {log_path}", flush=True)
    samples: list[dict[str, Any]] = []
    hog = viewer = None
    lags: list[float] = []
    load0 = load_average()
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdout=log,
                                stderr=subprocess.STDOUT)
        launcher = psutil.Process(proc.pid)
        try:
            deadline = time.monotonic() + 600.0  # wait for racing to start
            while b"racing" not in log_path.read_bytes():
                if proc.poll() is not None or time.monotonic() > deadline:
                    print(f"soak: the stack did not start; see {log_path}", file=sys.stderr)
                    return 1
                time.sleep(1.0)
            if args.hog:
                hog = start_hog(hog_cpu())
                print(f"soak: hog (pid {hog.pid}) pinned to CPU {hog_cpu()}", flush=True)
            if serve is not None:
                from benchmarks.telemetry_load import HeadlessViewer

                try:
                    viewer = HeadlessViewer(out)
                except (RuntimeError, OSError) as exc:
                    print(f"soak: --viewer: {exc}; a headless Rerun viewer cannot run here",
                          file=sys.stderr)
                    return 1
                viewer.open(f"rerun+http://127.0.0.1:{serve}/proxy", settle_s=0.0)
                viewer.sample_lag()
                print(f"soak: headless Rerun viewer (pid {viewer.proc.pid}) connected to "
                      f"127.0.0.1:{serve}", flush=True)
            t0 = time.monotonic()
            end = t0 + args.minutes * 60.0
            next_sample = t0
            while time.monotonic() < end:
                if proc.poll() is not None:
                    print(f"soak: the stack ended early (code {proc.returncode}); "
                          f"see {log_path}", file=sys.stderr)
                    break
                now = time.monotonic()
                if now >= next_sample:
                    size, nseg = recording_bytes(run_dir)
                    sample = {"t_s": now - t0, "rss_mb": rss_by_service(launcher),
                              "rrd_bytes": size, "segments": nseg}
                    samples.append(sample)
                    next_sample += args.sample_s
                    if len(samples) % max(1, round(60.0 / args.sample_s)) == 1:
                        rss = ", ".join(f"{k} {v:.0f}" for k, v in sample["rss_mb"].items())
                        print(f"  t {sample['t_s'] / 60:5.1f} min  RSS [MB] {rss};  "
                              f"recording {size / MB:.1f} MB in {nseg} segments", flush=True)
                time.sleep(min(1.0, max(0.0, next_sample - time.monotonic())))
        except KeyboardInterrupt:
            print("soak: interrupted; the figures below cover what was sampled", flush=True)
        finally:
            if viewer is not None:
                lags = viewer.stop()
            if hog is not None:
                stop_process(hog, grace_s=2.0)
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=120.0)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout=30.0)
    warmup_s = args.warmup_min * 60.0
    table = growth_table(samples, warmup_s, max(args.segment_s, args.sample_s))
    rate = slope_mb_per_min(samples, warmup_s)
    files = find_segments(run_dir) if run_dir.is_dir() else []
    ok, bad = verify(files, env)
    m = misses(read_logs(run_dir / "logs"), log_path.read_text(errors="replace"))
    laps = m["laps"]
    duration = samples[-1]["t_s"] / 60.0 if samples else 0.0
    print(f"\nsoak: {duration:.1f} min of racing, {laps} laps, {len(samples)} samples "
          f"every {args.sample_s:g} s; growth from t = {args.warmup_min:g} min to the end")
    print(f"(RSS at {args.warmup_min:g} min and at the end: the largest sample of one segment "
          f"length, {args.segment_s:g} s)")
    print(f"{'service':<22}{'RSS@warm MB':>12}{'RSS end MB':>12}{'max MB':>9}{'growth %':>10}")
    for r in table:
        print(f"{r['service']:<22}{r['rss_warm_mb']:>12.1f}{r['rss_end_mb']:>12.1f}"
              f"{r['rss_max_mb']:>9.1f}{r['growth_pct']:>10.1f}")
    size, nseg = recording_bytes(run_dir)
    print(f"recording: {size / MB:.1f} MB in {nseg} segments, growing {rate:.2f} MB/min "
          f"after the warm-up; {ok}/{len(files)} segments pass `rerun rrd verify`")
    for line in bad:
        print(f"  not verified: {line}")
    worst = max((r["growth_pct"] for r in table), default=float("nan"))
    memory_ok = bool(table) and worst <= GROWTH_LIMIT_PCT and not bad
    ages = m["stale_ages_ms"]
    print(f"load average {load0} at the start, {load_average()} at the end")
    print(f"stale-state brakes (planner): {m['stale_brakes']}"
          + (f", ages {min(ages)}-{max(ages)} ms (median {np.median(ages):.0f})" if ages else ""))
    print(f"localisation-invalid reports (bridge, rate-limited): {m['localisation_invalid']}")
    if args.pose_source == "lidar":
        print(f"pf_lost (bridge's lidar filter): {m['pf_lost']}")
    if m["skips"] is None:
        print("simulator: no closing line in its log (did it stop cleanly?)")
    else:
        rate = "" if m["world_rate"] is None else (
            f", longest {m['longest_slowdown_s']:.3f} s; the world ran at "
            f"{m['world_rate']:.3f} of real time")
        print(f"simulator: {m['overruns']} real-time overruns, {m['skips']} skips ahead "
              f"({m['skipped_s']:.2f} s), {m['slowdowns']} slowdowns of its world "
              f"({m['slowed_s']:.2f} s{rate})")
    print(f"off-track events: {m['off_track']}; laps: {laps}")
    if serve is not None:
        lag = np.asarray(lags, dtype=float)
        print("viewer lag behind the wall clock [s]: " + (
            f"median {np.median(lag):.2f}, p99 {np.percentile(lag, 99):.2f}, max "
            f"{lag.max():.2f} ({lag.size} samples)" if lag.size else "no samples"))
    checks = verdicts(m, worst, memory_ok)
    for line in checks:
        print(line)
    passed = all(line.startswith("PASS") for line in checks)
    (out / "soak.json").write_text(json.dumps({
        "minutes": duration, "laps": laps, "sample_s": args.sample_s, "misses": m,
        "hog": args.hog, "pose_source": args.pose_source, "viewer_lag_s": lags,
        "warmup_min": args.warmup_min, "table": table, "recording_mb_per_min": rate,
        "recording_bytes": size, "segments": nseg, "verified": ok, "not_verified": bad,
        "samples": samples}, indent=1) + "\n", encoding="utf-8")
    print(f"samples: {out / 'soak.json'}")
    return 0 if passed else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="racing time [min]")
    ap.add_argument("--warmup-min", type=float, default=None,
                    help="growth is measured from this time on [min] (default: 5 min, or "
                         "a third of --minutes when that is shorter than 15)")
    ap.add_argument("--sample-s", type=float, default=10.0, help="RSS sample period [s]")
    ap.add_argument("--track", default="builtin:paperlike", help="track to race")
    ap.add_argument("--laps", type=int, default=100_000,
                    help="laps asked of racestack up (more than fit: the time ends the soak)")
    ap.add_argument("--segment-s", type=float, default=60.0,
                    help="[telemetry] segment_interval_s of the run [s]")
    ap.add_argument("--lidar-hz", type=float, default=None,
                    help="[simulator.lidar] rate_hz (default: 10 Hz, 40 Hz with "
                         "--pose-source lidar)")
    ap.add_argument("--hog", action="store_true",
                    help="a busy loop pinned to the last CPU while racing (default: off)")
    ap.add_argument("--pose-source", choices=("external", "lidar"), default="external",
                    help="[localization] pose_source (default: external)")
    ap.add_argument("--viewer", action="store_true",
                    help="up --serve and a headless Rerun viewer connected to it "
                         "(default: off)")
    ap.add_argument("--config-extra", default="",
                    help="TOML appended to the run's configuration, e.g. "
                         "'[processes.simulator]\\nrealtime_priority = 10' (default: none)")
    ap.add_argument("--out", help="folder for the run, its log and soak.json (default: temp)")
    args = ap.parse_args(argv)
    if args.warmup_min is None:
        args.warmup_min = min(5.0, args.minutes / 3.0)
    if not 0.0 <= args.warmup_min < args.minutes:
        ap.error(f"--warmup-min {args.warmup_min:g} must be shorter than --minutes "
                 f"{args.minutes:g} (no memory sample would follow the warm-up)")
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
