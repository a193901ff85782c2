"""``racestack certs``: the files, their permissions, no overwrite, a bad folder."""

from __future__ import annotations

import stat
import subprocess
import sys
from pathlib import Path

from cryptography import x509
from cryptography.x509.oid import NameOID

from services.tools.cli import main
from shared.security import IDENTITIES

ROOT = Path(__file__).resolve().parents[2]


def test_makes_a_ca_and_one_certificate_per_identity(tmp_path: Path, capsys) -> None:
    out = tmp_path / "certs"
    assert main(["certs", "--out", str(out), "--host", "10.0.0.5"]) == 0
    ca = x509.load_pem_x509_certificate((out / "ca.crt").read_bytes())
    assert stat.S_IMODE((out / "ca.key").stat().st_mode) == 0o600
    for name in IDENTITIES:
        cert = x509.load_pem_x509_certificate((out / f"{name}.crt").read_bytes())
        cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
        assert cn == name and cert.issuer == ca.subject
        cert.verify_directly_issued_by(ca)
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert "localhost" in san.get_values_for_type(x509.DNSName)
        ips = {str(a) for a in san.get_values_for_type(x509.IPAddress)}
        assert ips == {"127.0.0.1", "10.0.0.5"}
        assert stat.S_IMODE((out / f"{name}.key").stat().st_mode) == 0o600
    assert "planner.key" in capsys.readouterr().out


def test_refuses_to_overwrite_without_force(tmp_path: Path, capsys) -> None:
    out = tmp_path / "certs"
    assert main(["certs", "--out", str(out)]) == 0
    before = (out / "planner.crt").read_bytes()
    capsys.readouterr()
    assert main(["certs", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--force" in err
    assert (out / "planner.crt").read_bytes() == before
    assert main(["certs", "--out", str(out), "--force"]) == 0
    assert (out / "planner.crt").read_bytes() != before


def test_unusable_folder_is_one_line_exit_2(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = subprocess.run(
        [sys.executable, "-m", "services.tools.cli", "certs", "--out", str(blocker / "certs")],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "not writable" in r.stderr
    assert r.stdout == ""
