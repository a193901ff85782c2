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
