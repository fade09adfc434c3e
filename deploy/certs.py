"""`cinetransfer deploy certs DIR`: a private CA, per-host certificates and passwords.

A split deployment gets one folder per host, each holding only what that host needs:

    DIR/ground/     ca.pem, ca-key.pem (the CA's key never leaves the ground station),
                    ground.pem + ground-key.pem (its router),
                    users.txt: passwords of the ground nodes, the tools and the ground link
    DIR/onboard/    ca.pem, onboard.pem + onboard-key.pem (its router),
                    users.txt: passwords of the onboard nodes, its own tools, and the ground link's
                    (the onboard router is the one that checks it),
                    mavlink-signing.key: the MAVLink 2 signing key of the vehicle link (docs/mavlink.md)

so a stolen ground folder holds no password an onboard node joins with, and a stolen drone holds
no CA key. `--one-host` writes a single folder with every identity (what `deploy up local`
generates for itself):

    ca.pem, ca-key.pem, <identity>.pem + -key.pem, users.txt (`identity:password` lines),
    mavlink-signing.key

Keys and passwords are written 0600 in a 0700 folder; nothing is overwritten unless --force.
Certificates carry `localhost`, 127.0.0.1 and every --host as subject alternative names, since
a TLS client checks the name it dialled against the certificate of the router it reaches.
"""
from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import secrets
import sys
from pathlib import Path

from cinetransfer.shared import access
from cinetransfer.shared.atomic import atomic_write
from cinetransfer.shared.signing_key import write_signing_key

CA_NAME = "cinetransfer-ca"
VALID_DAYS = 825  # the longest validity most TLS stacks accept for a leaf certificate
USERS_FILE = "users.txt"


def _write_private(path: Path, data: bytes) -> None:
    """Write `data` to `path` with mode 0600, via a unique temporary name and a rename."""
    with atomic_write(path, binary=True, mode=0o600) as f:
        f.write(data)


def _san(hosts: list[str]):
    from cryptography import x509

    names: list = []
    for h in ["localhost", "127.0.0.1", *hosts]:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            names.append(x509.DNSName(h))
    return x509.SubjectAlternativeName(list(dict.fromkeys(names)))


def _name(cn: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "cinetransfer"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _pem_key(key) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


class _CA:
    """A fresh certificate authority that issues the deployment's certificates."""

    def __init__(self) -> None:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes
        from cryptography.hazmat.primitives.asymmetric import ec

        self.now = dt.datetime.now(dt.timezone.utc) - dt.timedelta(minutes=5)  # tolerate small clock skew
        self.key = ec.generate_private_key(ec.SECP256R1())
        self.cert = (x509.CertificateBuilder().subject_name(_name(CA_NAME)).issuer_name(_name(CA_NAME))
                     .public_key(self.key.public_key()).serial_number(x509.random_serial_number())
                     .not_valid_before(self.now).not_valid_after(self.now + dt.timedelta(days=VALID_DAYS))
                     .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
                     .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                                  content_commitment=False, key_encipherment=False,
                                                  data_encipherment=False, key_agreement=False,
                                                  encipher_only=False, decipher_only=False), critical=True)
                     .sign(self.key, hashes.SHA256()))

    def write(self, out: Path, *, with_key: bool) -> list[Path]:
        from cryptography.hazmat.primitives import serialization

        _write_private(out / "ca.pem", self.cert.public_bytes(serialization.Encoding.PEM))
        if not with_key:
            return [out / "ca.pem"]
        _write_private(out / "ca-key.pem", _pem_key(self.key))
        return [out / "ca-key.pem", out / "ca.pem"]

    def issue(self, out: Path, ident: str, hosts: list[str]) -> list[Path]:
        """`ident`.pem (CN = ident) and its key in `out`."""
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import ExtendedKeyUsageOID

        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder().subject_name(_name(ident)).issuer_name(self.cert.subject)
                .public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(self.now).not_valid_after(self.now + dt.timedelta(days=VALID_DAYS))
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .add_extension(_san(hosts), critical=False)
                .sign(self.key, hashes.SHA256()))
        _write_private(out / f"{ident}-key.pem", _pem_key(key))
        _write_private(out / f"{ident}.pem", cert.public_bytes(serialization.Encoding.PEM))
        return [out / f"{ident}-key.pem", out / f"{ident}.pem"]


def _new_folder(out: Path, force: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, 0o700)
    existing = [p for p in (out / "ca.pem", out / USERS_FILE) if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{existing[0]} exists; use --force to replace every credential in {out}")


def _write_users(out: Path, passwords: dict[str, str]) -> Path:
    _write_private(out / USERS_FILE, "".join(f"{u}:{pw}\n" for u, pw in passwords.items()).encode())
    return out / USERS_FILE


def _passwords(names) -> dict[str, str]:
    return {u: secrets.token_urlsafe(24) for u in dict.fromkeys(names)}


def generate(out: Path, *, identities: tuple[str, ...] = access.CERT_IDENTITIES, users: tuple[str, ...] = (),
             hosts: list[str] | None = None, force: bool = False) -> list[Path]:
    """Create the one-host secrets folder `out` (every identity; see the module docstring)."""
    _new_folder(out, force)
    ca = _CA()
    written = ca.write(out, with_key=True)
    for ident in identities:
        written += ca.issue(out, ident, list(hosts or []))
    written.append(_write_users(out, _passwords([*access.USER_IDENTITIES, *users])))
    written.append(write_signing_key(out))
    return written


def generate_split(out: Path, *, hosts: list[str] | None = None, force: bool = False) -> list[Path]:
    """Create `out`/ground and `out`/onboard, each with only its host's secrets (module docstring)."""
    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, 0o700)
    folders = {h: out / h for h in access.HOST_USERS}
    for folder in folders.values():
        _new_folder(folder, force)
    ca = _CA()
    passwords = {h: _passwords(users) for h, users in access.HOST_USERS.items()}
    passwords["onboard"]["ground"] = passwords["ground"]["ground"]  # the onboard router checks the ground link
    written: list[Path] = []
    for h, folder in folders.items():
        written += ca.write(folder, with_key=h == "ground")
        for ident in access.HOST_CERTS[h]:
            written += ca.issue(folder, ident, list(hosts or []))
        written.append(_write_users(folder, passwords[h]))
    written.append(write_signing_key(folders["onboard"]))  # the bridge signs the vehicle link onboard
    return written


def ensure(out: Path, users: list[str] | tuple[str, ...] = ()) -> bool:
    """Generate the secrets folder if it has no credentials yet (True), else add missing `users`."""
    if not ((out / USERS_FILE).exists() and (out / "ca.pem").exists()):
        generate(out, users=tuple(users), force=True)
        return True
    text = (out / USERS_FILE).read_text()
    have = {line.partition(":")[0] for line in text.splitlines()}
    missing = [u for u in users if u not in have]
    if missing:
        text += "".join(f"{u}:{secrets.token_urlsafe(24)}\n" for u in missing)
        _write_private(out / USERS_FILE, text.encode())
    return False


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer deploy certs", description=__doc__.splitlines()[0])
    p.add_argument("dir", help="folder to create: DIR/ground and DIR/onboard (0700), each with its host's "
                               "certificates, keys and passwords")
    p.add_argument("--host", action="append", default=[], metavar="NAME_OR_IP",
                   help="address a TLS router is reached at, e.g. the drone's IP (repeatable)")
    p.add_argument("--one-host", action="store_true",
                   help="one folder DIR with every identity, for a deployment on a single host")
    p.add_argument("--force", action="store_true", help="replace existing credentials")
    args = p.parse_args(argv)
    out = Path(args.dir)
    try:
        if args.one_host:
            files = generate(out, hosts=args.host, force=args.force)
        else:
            files = generate_split(out, hosts=args.host, force=args.force)
    except FileExistsError as e:
        print(f"cinetransfer deploy certs: {e}", file=sys.stderr)
        return 1
    if args.one_host:
        print(f"wrote {len(files)} files to {out.resolve()}/ (keys 0600); run  CT_SECRETS={args.dir} "
              f"cinetransfer deploy up local")
    else:
        print(f"wrote {len(files)} files to {out.resolve()}/ground and /onboard (keys 0600); copy only "
              f"{args.dir}/onboard to the drone:  CT_SECRETS={args.dir}/onboard cinetransfer deploy up onboard; "
              f"on the ground:  CT_SECRETS={args.dir}/ground cinetransfer deploy up ground")
    return 0
