"""Issue #16: every command's --help works (exit 0), shows no RST backticks, and says what
the options newcomers asked about do."""

from __future__ import annotations

import argparse

import pytest

from services.tools import cli


def _help(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exc:
        code = cli.main([*argv, "--help"])
        raise SystemExit(code)
    out, err = capsys.readouterr()
    assert exc.value.code in (0, None), err
    return out


def _subcommands() -> list[str]:
    ap = cli.build_parser()
    sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
    return sorted(sub.choices)


def test_cli_help_of_racestack_itself(capsys: pytest.CaptureFixture[str]) -> None:
    out = _help([], capsys)
    assert "``" not in out
    for name in _subcommands():
        assert name in out


@pytest.mark.parametrize("name", _subcommands())
def test_cli_help_of_every_subcommand(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = _help([name], capsys)
    assert out.strip() and "``" not in out


@pytest.mark.parametrize("service", cli.SERVICES)
def test_cli_help_of_every_service(service: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["run", service, "--help"])
    out, _ = capsys.readouterr()
    assert code == 0 and "``" not in out and f"racestack run {service}" in out
    desc = out.split("\n\n")[1]  # usage, then the description paragraph
    assert desc.rstrip().endswith((".", ")")), f"cut off: {desc!r}"


def test_cli_help_texts_newcomers_asked_for(capsys: pytest.CaptureFixture[str]) -> None:
    up = " ".join(_help(["up"], capsys).split())
    assert "timed laps to race" in up and "rerun --connect" in up
    bench = " ".join(_help(["bench"], capsys).split())
    assert "previous command still acts" in bench  # --compute-delay-ms
    assert "results.json only" in bench  # --no-figures
    report = _help(["report"], capsys)  # its options, with no recording given
    for opt in ("--out", "--track", "--config", "--no-figures", "recording"):
        assert opt in report
