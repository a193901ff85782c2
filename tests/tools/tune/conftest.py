"""A throwaway PostgreSQL server for the tuner's RDB-storage tests (``postgres_url``).

The machine's own binaries (Debian's ``postgresql`` package: ``/usr/lib/postgresql/*/bin``;
``make test`` installs it when it is missing and apt is there) make a cluster in a temporary
folder and serve it on 127.0.0.1 at a free port, with trust authentication and its socket in
that folder. initdb refuses root, so as root the cluster belongs to the package's
``postgres`` user (else ``nobody``). The server is this fixture's own child process: it is
stopped by its PID at the end (SIGINT, PostgreSQL's fast shutdown; SIGKILL after a timeout).
Skips, saying why, without the binaries, without a usable user or without the driver.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from shared.net import free_loopback_port

#: Seconds the server may take to accept connections, and to stop.
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 30.0
#: The database role the tests use.
ROLE = "racestack"


def postgres_bin_dir() -> Path | None:
    """The newest ``/usr/lib/postgresql/N/bin`` holding initdb and postgres, or None."""
    dirs = [Path(p).parent for p in glob.glob("/usr/lib/postgresql/*/bin/initdb")]
    dirs = [d for d in dirs if (d / "postgres").is_file()]
    if not dirs:
        return None
    return max(dirs, key=lambda d: int(d.parent.name) if d.parent.name.isdigit() else 0)


def _run_as() -> pwd.struct_passwd | None:
    """The user the server runs as: ourselves unless root (``postgres``, else ``nobody``)."""
    if os.geteuid() != 0:
        return pwd.getpwuid(os.geteuid())
    for name in ("postgres", "nobody"):
        try:
            return pwd.getpwnam(name)
        except KeyError:
            continue
    return None


def _ready(url: str) -> bool:
    import sqlalchemy

    try:
        engine = sqlalchemy.create_engine(url)
        with engine.connect() as conn:
            conn.execute(sqlalchemy.text("select 1"))
        engine.dispose()
        return True
    except sqlalchemy.exc.OperationalError:
        return False


@pytest.fixture(scope="module")
def postgres_url() -> Iterator[str]:
    """``postgresql+psycopg2://racestack@127.0.0.1:PORT/postgres`` of a server started for
    this test module (module docstring)."""
    bin_dir = postgres_bin_dir()
    if bin_dir is None:
        pytest.skip("PostgreSQL is not installed (no /usr/lib/postgresql/*/bin/initdb; Debian: "
                    "apt-get install postgresql, which make test does when it can)")
    pytest.importorskip("psycopg2", reason="needs the PostgreSQL driver psycopg2 (pip install "
                        "-e '.[tools]')")
    user = _run_as()
    if user is None:
        pytest.skip("running as root and no 'postgres' or 'nobody' user to run PostgreSQL as")
    # a folder of its own under the system's temp dir (world-passable, unlike pytest's
    # per-user base folder), for the server's user
    root = Path(tempfile.mkdtemp(prefix="racestack-pg-"))
    data = root / "data"
    data.mkdir()
    for p in (root, data):
        os.chown(p, user.pw_uid, user.pw_gid)
        p.chmod(0o700)
    as_user = {"user": user.pw_uid, "group": user.pw_gid, "extra_groups": []} \
        if os.geteuid() == 0 else {}
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LC_ALL": "C", "LANG": "C"}
    init = subprocess.run(
        [str(bin_dir / "initdb"), "-D", str(data), "-U", ROLE, "-A", "trust", "-E", "UTF8",
         "--no-sync"],
        capture_output=True, text=True, timeout=120, env=env, cwd=root, **as_user,
    )
    if init.returncode != 0:
        pytest.fail(f"initdb failed: {init.stderr.strip()[-500:]}")
    port = free_loopback_port()
    log = (root / "server.log").open("w")
    server = subprocess.Popen(
        [str(bin_dir / "postgres"), "-D", str(data), "-h", "127.0.0.1", "-p", str(port),
         "-k", str(root), "-c", "fsync=off", "-c", "max_connections=50"],
        stdout=log, stderr=subprocess.STDOUT, env=env, cwd=root, **as_user,
    )
    url = f"postgresql+psycopg2://{ROLE}@127.0.0.1:{port}/postgres"
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not _ready(url):
            if server.poll() is not None or time.monotonic() > deadline:
                text = (root / "server.log").read_text(errors="replace")[-800:]
                pytest.fail(f"PostgreSQL did not start (exit {server.poll()}): {text}")
            time.sleep(0.2)
        yield url
    finally:
        if server.poll() is None:
            os.kill(server.pid, signal.SIGINT)  # fast shutdown
            try:
                server.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                os.kill(server.pid, signal.SIGKILL)
                server.wait(timeout=STOP_TIMEOUT_S)
        log.close()
        shutil.rmtree(root, ignore_errors=True)
