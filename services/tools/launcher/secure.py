"""``racestack up`` in the secure profile (``[bus] security = "mtls"``): certificates and hub.

The rule for the certificates: ``[bus] certs_dir`` (resolved against the working directory,
or ``$RACESTACK_CERTS_DIR`` if set) is used when it holds ``ca.crt``; then every identity the
run needs (the router, the launcher and each started service) must have its ``.crt`` and
``.key`` there, else ``up`` does not start and says which are missing. When that folder has
no ``ca.crt``, a throwaway CA and certificates are made in ``<run folder>/certs`` for this
run only, and ``$RACESTACK_CERTS_DIR`` points this process and its children at them.

The hub: in this profile the launcher does not host the router; it starts ``services.router``
first (the only process with the access rules, which counts their denials), waits until its
endpoint accepts connections, then joins it as the client ``launcher`` like every service.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

from services.tools.launcher.supervisor import Supervisor, service_argv
from shared.config import RacestackConfig
from shared.config.bus import parse_endpoint
from shared.outdir import writable_dir_problem
from shared.roster import hub as roster_hub
from shared.security.identities import CA_CERT, CERTS_DIR_ENV, HUB_IDENTITY, identity_files
from shared.service_shell import endpoint_reachable

#: How long the router may take to listen [s].
HUB_START_TIMEOUT_S = 30.0


def certs_dir_for_run(
    configured: Path, run_dir: Path, identities: tuple[str, ...]
) -> tuple[Path, bool] | str:
    """(the certificates folder, True if it was made now) or one line saying why not.

    Args:
        configured: the configured folder (``[bus] certs_dir`` or the environment's).
        run_dir: the run folder (where a throwaway set goes).
        identities: who needs a certificate in this run.
    """
    if (configured / CA_CERT).is_file():
        missing = [str(p) for i in identities for p in identity_files(configured, i).missing()]
        if missing:
            return (f"secure profile: {configured} lacks {', '.join(missing[:4])}"
                    f"{' ...' if len(missing) > 4 else ''} (racestack certs --out "
                    f"{configured} --force makes a full set)")
        return configured, False
    from shared.security.certs import CertsError, make_certs
    from shared.security.identities import IDENTITIES

    out = run_dir / "certs"
    try:  # the known identities and the run's own (each car's services in a race)
        make_certs(out, tuple(dict.fromkeys((*IDENTITIES, *identities))), force=True)
    except CertsError as exc:
        return f"secure profile: {exc}"
    return out, True


def hub_endpoint(cfg: RacestackConfig) -> str:
    """The endpoint the launcher reaches the router at (its own client plan)."""
    plan = cfg.bus.session_plan(listen_default=False, service="launcher",
                                certs_dir=os.environ.get(CERTS_DIR_ENV) or None)
    return plan.connect[0]


def run_secure(
    cfg: RacestackConfig,
    config_path: str | None,
    run_dir: Path,
    services: tuple[str, ...],
    race: Callable[[], int],
) -> int:
    """Make or check the certificates, start the router, run `race`, stop the router."""
    problem = writable_dir_problem(run_dir)
    if problem:
        return _cannot_start(f"{problem}; give --run-dir a folder you can write")
    configured = Path(os.environ.get(CERTS_DIR_ENV) or cfg.bus.certs_dir)
    got = certs_dir_for_run(configured, run_dir, (HUB_IDENTITY, "launcher", *services))
    if isinstance(got, str):
        return _cannot_start(got)
    certs, made = got
    if made:
        os.environ[CERTS_DIR_ENV] = str(certs.resolve())  # this process and its children
        print(f"secure profile: made a throwaway CA and certificates in {certs} "
              f"(no {CA_CERT} in {configured})", flush=True)
    else:
        print(f"secure profile: certificates from {certs}", flush=True)
    endpoint = hub_endpoint(cfg)
    ep = parse_endpoint(endpoint)
    with Supervisor(log_dir=run_dir / "logs") as hub:
        router = roster_hub().name  # the process; HUB_IDENTITY is its certificate's name
        child = hub.start(router, service_argv(router, config_path))
        tcp = f"tcp/{ep.host}:{ep.port}"
        if not hub.wait_until(lambda: endpoint_reachable(tcp), HUB_START_TIMEOUT_S):
            return _cannot_start(f"the router did not listen on {endpoint} within "
                                 f"{HUB_START_TIMEOUT_S:.0f} s; log: {child.log_path}")
        print(f"secure profile: router (pid {child.pid}) listening on {endpoint}", flush=True)
        return race()


def _cannot_start(line: str) -> int:
    print(f"racestack up: error: {line}", file=sys.stderr, flush=True)
    return 2


