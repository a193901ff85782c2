"""``racestack certs --out DIR [--force] [--host H ...] [--days N]``: the command line of
``shared.security.certs`` (exit 0 with the files listed; 2 with one line on stderr)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from shared.security.identities import IDENTITIES


def certs_parser(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of ``racestack certs`` to `ap`."""
    ap.description = (
        "Make a local certificate authority and one TLS certificate per identity "
        f"({', '.join(IDENTITIES)}) for [bus] security = \"mtls\"."
    )
    ap.add_argument("--out", required=True, help="the certificates folder ([bus] certs_dir)")
    ap.add_argument("--force", action="store_true", help="replace certificates already there "
                    "(default: refuse, one line, when any file exists)")
    ap.add_argument(
        "--host",
        action="append",
        default=[],
        metavar="H",
        help="another DNS name or IP address the hub is reached at (repeatable), e.g. the "
        "car's address for a laptop; localhost and 127.0.0.1 are always in (default: "
        "those two only)",
    )
    ap.add_argument("--days", type=int, default=None, help="validity [days] (default 825)")
    return ap


def certs_main(args: argparse.Namespace) -> int:
    """Run ``racestack certs``; the exit code."""
    from shared.security.certs import DEFAULT_DAYS, DEFAULT_HOSTS, CertsError, make_certs

    hosts = tuple(dict.fromkeys([*DEFAULT_HOSTS, *args.host]))
    out = Path(args.out)
    try:
        written = make_certs(
            out, hosts=hosts, days=DEFAULT_DAYS if args.days is None else args.days,
            force=args.force,
        )
    except CertsError as exc:
        print(f"racestack certs: error: {exc}", file=sys.stderr)
        return 2
    print(f"racestack certs: a CA and {len(IDENTITIES)} certificates in {out} "
          f"(hosts {', '.join(hosts)}; keys mode 0600):")
    for path in written:
        print(f"  {path}")
    print(f'use it with [bus] security = "mtls" and certs_dir = "{out}"; keep ca.key off '
          "the car once the certificates are made")
    return 0
