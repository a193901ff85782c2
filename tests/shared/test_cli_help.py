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


def _option_parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    """Every parser of racestack: itself, each subcommand, and report's own (its options
    are parsed by services.tools.report)."""
    from services.tools.report import build_parser as report_parser

    ap = cli.build_parser()
    sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
    return [("racestack", ap), *sorted(sub.choices.items()), ("report", report_parser())]


def test_every_option_of_every_subcommand_says_what_it_does_and_its_default() -> None:
    """Issue #22: no option without help, and every option that is not required says what
    happens without it ("default ..."), whatever its argparse default is."""
    missing = []
    for name, parser in _option_parsers():
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction | argparse._SubParsersAction):
                continue
            text = (action.help or "").strip()
            opt = "/".join(action.option_strings) or action.dest
            if not text or text == argparse.SUPPRESS:
                missing.append(f"{name} {opt}: no help")
            elif action.option_strings and not action.required and "default" not in text.lower():
                missing.append(f"{name} {opt}: no default said ({action.default!r})")
    assert not missing, "\n".join(missing)


def test_the_defaults_newcomers_asked_for_are_in_the_help(capsys) -> None:
    bench = " ".join(_help(["bench"], capsys).split())
    assert "default 17" in bench and "default cimpcc,mpcc" in bench  # --laps, --methods
    assert "default 3)" in bench and "MAP.yaml" in bench  # --sweep-laps; --track takes maps
    mintime = " ".join(_help(["mintime"], capsys).split())
    assert "no PNG figures (default: the figures too" in mintime
    up = " ".join(_help(["up"], capsys).split())
    assert "--track" in up and "--method" in up and "launcher.log" in up
