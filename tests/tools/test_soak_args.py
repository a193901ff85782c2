"""The soak benchmark's arguments: a warm-up that leaves no memory sample is refused."""

import pytest

from benchmarks import soak


def test_a_warm_up_as_long_as_the_soak_is_refused_with_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        soak.main(["--minutes", "5", "--warmup-min", "5"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--warmup-min 5 must be shorter than --minutes 5" in err


def test_the_default_warm_up_of_a_short_soak_is_a_third_of_it(monkeypatch):
    seen = {}
    monkeypatch.setattr(soak, "run", lambda args: seen.setdefault("w", args.warmup_min) and 0)
    soak.main(["--minutes", "6"])
    assert seen["w"] == pytest.approx(2.0)
    seen.clear()
    soak.main(["--minutes", "30"])
    assert seen["w"] == pytest.approx(5.0)


def test_config_extra_adds_to_the_soak_s_own_tables(tmp_path):
    import tomllib

    from shared.config import load_config

    extra = ("[telemetry]\nserve_memory_limit_mb = 64\n\n"
             "[processes.simulator]\nrealtime_priority = 10\n")
    path = soak.soak_config(tmp_path / "soak.toml", 7999, "builtin:paperlike", 30.0, 10.0,
                            "lidar", extra)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    assert data["telemetry"] == {"segment_interval_s": 30.0, "serve_memory_limit_mb": 64}
    assert data["simulator"]["lidar"]["rate_hz"] == 10.0
    assert data["bus"]["listen"] == ["tcp/127.0.0.1:7999"]
    cfg = load_config(path)  # and the stack reads it
    assert cfg.telemetry.serve_memory_limit_mb == 64
    assert cfg.localization.pose_source == "lidar"


def test_config_extra_that_is_not_toml_is_one_line(tmp_path):
    with pytest.raises(ValueError, match="--config-extra is not valid TOML"):
        soak.soak_config(tmp_path / "soak.toml", 7999, "builtin:paperlike", 30.0, 10.0,
                         extra="[telemetry")
