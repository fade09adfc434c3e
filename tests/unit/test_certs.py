"""`cinetransfer deploy certs DIR`: a CA, certificates with the identity as CN, private files."""
import stat

from cryptography import x509
from cryptography.x509.oid import NameOID

from cinetransfer.deploy import certs, cli
from cinetransfer.shared import access


def _users(folder) -> dict[str, str]:
    return dict(line.split(":", 1) for line in (folder / "users.txt").read_text().splitlines())


def test_certs_cli_writes_one_folder_per_host_with_only_its_secrets(tmp_path):
    out = tmp_path / "sec"
    assert cli.main(["certs", str(out), "--host", "192.0.2.10"]) == 0
    ground, onboard = out / "ground", out / "onboard"
    assert sorted(f.name for f in ground.iterdir()) == ["ca-key.pem", "ca.pem", "ground-key.pem", "ground.pem",
                                                        "users.txt"]
    # the drone gets no CA key and no other host's key; it signs the vehicle link, so the MAVLink key is there only
    assert sorted(f.name for f in onboard.iterdir()) == ["ca.pem", "mavlink-signing.key", "onboard-key.pem",
                                                         "onboard.pem", "users.txt"]
    for folder in (out, ground, onboard):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    g, o = _users(ground), _users(onboard)
    # each host knows only the passwords of what runs on it (its tools with passwords of their own)
    assert not {"planner", "autopilot_bridge", "onboard"} & set(g)
    assert not {"source", "detector", "smoother", "camera"} & set(o)
    assert g["operator"] != o["operator"] and g["observer"] != o["observer"]
    # the onboard router checks the ground link's login, so it holds that one password
    assert g["ground"] == o["ground"]
    ca = x509.load_pem_x509_certificate((ground / "ca.pem").read_bytes())
    assert (onboard / "ca.pem").read_bytes() == (ground / "ca.pem").read_bytes()
    x509.load_pem_x509_certificate((onboard / "onboard.pem").read_bytes()).verify_directly_issued_by(ca)


def test_certs_cli_one_host_writes_a_private_ca_and_per_identity_certificates(tmp_path, capsys):
    out = tmp_path / "sec"
    assert cli.main(["certs", str(out), "--one-host", "--host", "192.0.2.10", "--host", "drone.local"]) == 0
    assert stat.S_IMODE(out.stat().st_mode) == 0o700
    for f in out.iterdir():
        assert stat.S_IMODE(f.stat().st_mode) == 0o600, f
    ca = x509.load_pem_x509_certificate((out / "ca.pem").read_bytes())
    for ident in access.CERT_IDENTITIES:
        cert = x509.load_pem_x509_certificate((out / f"{ident}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == ident
        assert cert.issuer == ca.subject
        cert.verify_directly_issued_by(ca)
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert "drone.local" in san.get_values_for_type(x509.DNSName)
    users = dict(line.split(":", 1) for line in (out / "users.txt").read_text().splitlines())
    assert set(access.USER_IDENTITIES) <= set(users) and len(set(users.values())) == len(users)
    # a second run does not silently replace the credentials
    before = (out / "users.txt").read_text()
    assert cli.main(["certs", str(out), "--one-host"]) == 1
    assert "--force" in capsys.readouterr().err and (out / "users.txt").read_text() == before


def test_ensure_generates_once_and_adds_missing_users(tmp_path):
    out = tmp_path / "sec"
    assert certs.ensure(out, users=["relay_x"]) is True
    pw = access.read_password(out, "relay_x")
    assert certs.ensure(out, users=["relay_x", "relay_y"]) is False
    assert access.read_password(out, "relay_x") == pw and access.read_password(out, "relay_y")
