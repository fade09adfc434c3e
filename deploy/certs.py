"""`cinetransfer deploy certs DIR`: a private CA, one certificate per router/tool, and passwords.

One secrets folder serves a whole deployment (every host of a split deployment gets a copy):

    ca.pem                      the CA certificate every TLS endpoint trusts
    ca-key.pem                  the CA's private key (keep it off the vehicle; only needed to add certs)
    <identity>.pem, -key.pem    certificate (CN = identity) and key, for routers and remote tools
    users.txt                   `identity:password` lines: the routers' user/password dictionary
    mavlink-signing.key         the MAVLink 2 signing key of the vehicle link (docs/mavlink.md)

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


def generate(out: Path, *, identities: tuple[str, ...] = access.CERT_IDENTITIES, users: tuple[str, ...] = (),
             hosts: list[str] | None = None, force: bool = False) -> list[Path]:
    """Create the secrets folder `out` (see the module docstring); returns the files written."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID

    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, 0o700)
    existing = [p for p in (out / "ca.pem", out / USERS_FILE) if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{existing[0]} exists; use --force to replace every credential in {out}")
    now = dt.datetime.now(dt.timezone.utc) - dt.timedelta(minutes=5)  # tolerate small clock skew
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_cert = (x509.CertificateBuilder().subject_name(_name(CA_NAME)).issuer_name(_name(CA_NAME))
               .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now).not_valid_after(now + dt.timedelta(days=VALID_DAYS))
               .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
               .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                            content_commitment=False, key_encipherment=False,
                                            data_encipherment=False, key_agreement=False,
                                            encipher_only=False, decipher_only=False), critical=True)
               .sign(ca_key, hashes.SHA256()))
    written = []
    _write_private(out / "ca-key.pem", _pem_key(ca_key))
    _write_private(out / "ca.pem", ca_cert.public_bytes(serialization.Encoding.PEM))
    written += [out / "ca-key.pem", out / "ca.pem"]
    san = _san(list(hosts or []))
    for ident in identities:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder().subject_name(_name(ident)).issuer_name(ca_cert.subject)
                .public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(now).not_valid_after(now + dt.timedelta(days=VALID_DAYS))
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .add_extension(san, critical=False)
                .sign(ca_key, hashes.SHA256()))
        _write_private(out / f"{ident}-key.pem", _pem_key(key))
        _write_private(out / f"{ident}.pem", cert.public_bytes(serialization.Encoding.PEM))
        written += [out / f"{ident}-key.pem", out / f"{ident}.pem"]
    names = dict.fromkeys([*access.USER_IDENTITIES, *users])
    _write_private(out / USERS_FILE, "".join(f"{u}:{secrets.token_urlsafe(24)}\n" for u in names).encode())
    written.append(out / USERS_FILE)
    written.append(write_signing_key(out))
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
    p.add_argument("dir", help="folder to create (0700): CA, certificates, keys and users.txt")
    p.add_argument("--host", action="append", default=[], metavar="NAME_OR_IP",
                   help="address a TLS router is reached at, e.g. the drone's IP (repeatable)")
    p.add_argument("--force", action="store_true", help="replace existing credentials")
    args = p.parse_args(argv)
    try:
        files = generate(Path(args.dir), hosts=args.host, force=args.force)
    except FileExistsError as e:
        print(f"cinetransfer deploy certs: {e}", file=sys.stderr)
        return 1
    print(f"wrote {len(files)} files to {Path(args.dir).resolve()}/ (keys 0600); copy the folder to every host "
          f"and run e.g.  CT_SECRETS={args.dir} cinetransfer deploy up onboard")
    return 0
