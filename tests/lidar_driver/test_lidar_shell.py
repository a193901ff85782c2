"""Settings, the reconnecting link, and the service shell on ``FakeBus`` with the fake on a pty
(in process, no Zenoh): scans published, faults counted, a missing port waited for."""

from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest

from services.lidar_driver.link import Link
from services.lidar_driver.service import LidarService
from shared.bus.fake import FakeBus
from shared.config import ConfigError, config_from_dict
from shared.config.lidar import LidarDriverSettings
from shared.hokuyo.fake_io import FakeHokuyo, pty_available
from shared.messages import LogEvent, Scan


def test_settings_validate_and_sit_in_the_root_config() -> None:
    cfg = config_from_dict({"lidar_driver": {"port": "tcp://192.168.0.10:10940"}})
    assert cfg.lidar_driver.port.startswith("tcp://")
    for bad in (
        {"port": "tcp://nohost"},
        {"range_min_m": 5.0, "range_max_m": 1.0},
        {"first_step": 900, "last_step": 100},
        {"cluster": 0},
        {"stamp_source": "gps"},
        {"bogus": 1},
    ):
        with pytest.raises(ConfigError):
            config_from_dict({"lidar_driver": bad})


class FlakyOpener:
    """Opens a stand-in transport while ``present``; counts the calls."""

    def __init__(self) -> None:
        self.present = False
        self.calls = 0

    def __call__(self, address: str, baudrate: int) -> object:
        self.calls += 1
        if not self.present:
            raise OSError(2, "No such file or directory")
        return _Broken()


class _Broken:
    def read(self, n: int) -> bytes:
        raise OSError(5, "Input/output error")

    def write(self, data: bytes) -> None:
        raise OSError(5, "Input/output error")

    def fileno(self) -> int:
        return -1

    def close(self) -> None:
        pass


def test_link_retries_once_per_period_and_never_raises() -> None:
    opener = FlakyOpener()
    link = Link("/dev/none", reconnect_period_s=1.0, opener=opener)
    assert not link.maintain(0.0) and opener.calls == 1
    assert not link.maintain(0.5) and opener.calls == 1  # within the period
    opener.present = True
    assert link.maintain(1.0) and link.connected
    assert link.read() == b"" and not link.connected  # an I/O error closes it
    assert link.counters.losses == 1 and "Input/output" in (link.last_error or "")
    assert not link.write(b"QT\n")
    link.drop("silent", 2.0)
    assert link.counters.open_failures == 1


def run_until(svc: LidarService, cond, timeout_s: float = 5.0) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        svc.io_step()
        svc.poll()
        if cond():
            return True
    return False


@pytest.mark.skipif(not pty_available(), reason="needs pseudo-terminals (os.openpty)")
def test_the_shell_publishes_scans_and_reports_faults_and_a_missing_port(tmp_path) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(5)
    scans = [rng.integers(20, 25000, 1081) for _ in range(3)]
    with FakeHokuyo(scans, link_dir=tmp_path) as fake:
        fake.unplug()
        bus = FakeBus()
        s = LidarDriverSettings(
            port=fake.address, event_interval_s=0.0, reconnect_period_s=0.05, upside_down=True
        )
        svc = LidarService(s, bus)

        def logs() -> list[str]:
            return [e.text for e in bus.sent(bus.keys.events_log, LogEvent)]

        assert run_until(svc, lambda: any("waiting for the lidar port" in t for t in logs()))
        fake.replug()
        assert run_until(svc, lambda: len(bus.sent(bus.keys.scan, Scan)) >= 5)
        sc = bus.sent(bus.keys.scan, Scan)[0]
        assert sc.angle_min_rad == pytest.approx(math.radians(135.0))
        assert sc.angle_increment_rad == pytest.approx(-math.radians(0.25))
        assert any(np.array_equal(sc.ranges_m, (g / 1000.0).astype(np.float32)) for g in scans)
        fake.set(corrupt=1)
        assert run_until(svc, lambda: any("1 bad checksums" in t for t in logs()))
        d = svc.diagnostics()
        assert d["decoder.checksum_errors"] == 1 and d["service.published"] >= 5
        svc.close()


@pytest.mark.skipif(not pty_available(), reason="needs pseudo-terminals (os.openpty)")
def test_pure_noise_on_the_line_is_counted_and_reported_on_events_log(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Random bytes (no empty line) and junk lines between scans: the scans go on, every run
    of junk is one noise piece, and the count is said on events/log (rate limited)."""
    rng = np.random.default_rng(11)
    scans = [rng.integers(20, 25000, 1081) for _ in range(3)]
    noise = bytes(b for b in rng.integers(0, 256, 300, dtype=np.uint8).tobytes() if b != 0x0A)
    with FakeHokuyo(scans, link_dir=tmp_path) as fake:
        bus = FakeBus()
        svc = LidarService(
            LidarDriverSettings(port=fake.address, event_interval_s=0.2), bus
        )

        def logs() -> list[str]:
            return [e.text for e in bus.sent(bus.keys.events_log, LogEvent)]

        assert run_until(svc, lambda: len(bus.sent(bus.keys.scan, Scan)) >= 3)
        published = len(bus.sent(bus.keys.scan, Scan))
        for junk in (noise, b"junk line\n", b"#$%&\nanother one\n", noise):
            fake.set(garbage=junk)
            assert run_until(svc, lambda j=junk: fake.model.garbage != j)  # sent before a scan
        assert run_until(svc, lambda: svc.session.decoder.counters.no_echo >= 4)
        pattern = re.compile(r"(\d+) noise pieces")
        assert run_until(
            svc, lambda: any(int(n) >= 4 for t in logs() for n in pattern.findall(t))
        ), logs()
        assert len(bus.sent(bus.keys.scan, Scan)) > published + 2  # the stream went on
        reports = [t for t in logs() if "noise pieces" in t]
        assert len(reports) <= 5, reports  # rate limited: not one line per piece
        svc.close()
