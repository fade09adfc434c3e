"""Zenoh session configuration from a file, the environment and command-line flags.

Precedence (lowest first): safe defaults → a JSON5 config file (`--zenoh-config` or
$CT_ZENOH_CONFIG) → flags. Defaults differ from Zenoh's own on purpose: multicast scouting is
OFF (a peer would otherwise announce itself on every interface) and a peer listens on
127.0.0.1 only unless told otherwise.

Security (docs/security.md): with `secrets` (a folder from `cinetransfer deploy certs`) a
process joins as `identity` with that identity's password, a router checks every joiner against
the folder's users.txt, and tls/ endpoints use the folder's CA and the identity's certificate
with mutual authentication. A listener that leaves the host must be tls/ or quic/ with mTLS;
plain listeners are refused anywhere but on loopback. deploy/join.py is the one way for a tool
to join a running deployment as a given identity.
"""
from __future__ import annotations

import argparse
import json
import ipaddress
import os
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from cinetransfer.shared.errors import ConfigError

ENV_CONFIG = "CT_ZENOH_CONFIG"
MODES = ("peer", "client", "router")
SHM_POOL_BYTES = 64 * 1024 * 1024  # holds ~20 raw 720p frames in flight


@dataclass(frozen=True)
class ZenohOptions:
    """How a node joins the Zenoh network."""

    mode: str = "peer"
    listen: tuple[str, ...] = ()  # empty: Zenoh decides (a peer with no endpoints still connects out)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    shared_memory: bool = False
    config_file: str | None = None
    tls_root_ca: str | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    tls_mtls: bool = False
    identity: str | None = None  # who this process is (user name; certificate = <secrets>/<identity>.pem)
    secrets: str | None = None  # the deployment's secrets folder (users.txt, ca.pem, certificates)
    access_control: str | None = None  # JSON file with a Zenoh `access_control` object (routers)
    extra: tuple[tuple[str, str], ...] = field(default=())  # (key, json5 value) pairs

    def validate(self) -> None:
        """Raises ConfigError (a ValueError) naming the option."""
        if self.mode not in MODES:
            raise ConfigError(f"zenoh mode {self.mode!r} is not one of {', '.join(MODES)}")
        for ep in (*self.listen, *self.connect):
            if "/" not in ep:
                raise ConfigError(f"zenoh endpoint {ep!r} must look like 'tcp/127.0.0.1:7447'")
        self._validate_files()
        for ep in self.listen:
            self._validate_listener(ep)

    def _validate_files(self) -> None:
        for p in (self.config_file, self.tls_root_ca, self.tls_cert, self.tls_key):
            if p and not os.path.isfile(p):
                raise ConfigError(f"zenoh configuration file {p!r} does not exist")
        if bool(self.tls_cert) != bool(self.tls_key):
            raise ConfigError("--tls-cert and --tls-key must be given together")
        if self.secrets and not os.path.isdir(self.secrets):
            raise ConfigError(f"secrets folder {self.secrets!r} does not exist (cinetransfer deploy certs DIR)")
        if self.access_control and not os.path.isfile(self.access_control):
            raise ConfigError(f"access-control file {self.access_control!r} does not exist")

    def _validate_listener(self, ep: str) -> None:
        proto, host = endpoint_host(ep)
        if proto in ("tls", "quic"):
            if not (self.tls_mtls or self.secrets):
                raise ConfigError(f"listener {ep!r}: tls/quic listeners must require client certificates "
                                  f"(--mtls, or --secrets DIR which implies it)")
        elif not _is_local(proto, host):
            raise ConfigError(f"listener {ep!r} would accept unauthenticated connections from the network; "
                              f"listen on 127.0.0.1 or use tls/{host}:PORT with mTLS (docs/security.md)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The shared Zenoh flags every node and tool accepts."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--zenoh-config", metavar="FILE", default=None,
                   help=f"Zenoh JSON5 config file (default: ${ENV_CONFIG} if set)")
    g.add_argument("--mode", choices=MODES, default=None, help="Zenoh mode (default peer)")
    g.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--multicast-scouting", action="store_true", default=None,
                   help="enable UDP multicast scouting (off by default)")
    g.add_argument("--shm", action="store_true", default=None,
                   help=f"use shared memory for large messages on one host ({SHM_POOL_BYTES >> 20} MiB pool)")
    g.add_argument("--tls-root-ca", metavar="PEM", default=None, help="CA certificate for tls/ endpoints")
    g.add_argument("--tls-cert", metavar="PEM", default=None, help="this node's certificate (TLS/mTLS)")
    g.add_argument("--tls-key", metavar="PEM", default=None, help="this node's private key (TLS/mTLS)")
    g.add_argument("--mtls", action="store_true", default=None, help="require client certificates")
    g.add_argument("--identity", default=None, metavar="NAME",
                   help="join as this identity (its password from --secrets; see docs/security.md)")
    g.add_argument("--secrets", default=None, metavar="DIR",
                   help="deployment secrets folder (cinetransfer deploy certs DIR): users, CA, certificates")
    g.add_argument("--access-control", default=None, metavar="JSON",
                   help="router: file with the Zenoh access_control rules to enforce")


def options_from_args(args: argparse.Namespace, **defaults: object) -> ZenohOptions:
    """Build options: `defaults` (e.g. from a deploy config), then flags on top."""
    base = ZenohOptions(**defaults)  # type: ignore[arg-type]
    upd: dict[str, object] = {}
    cfg = getattr(args, "zenoh_config", None) or os.environ.get(ENV_CONFIG) or base.config_file
    if cfg:
        upd["config_file"] = cfg
    for name, attr in (("mode", "mode"), ("multicast_scouting", "multicast_scouting"),
                       ("shm", "shared_memory"), ("tls_root_ca", "tls_root_ca"), ("tls_cert", "tls_cert"),
                       ("tls_key", "tls_key"), ("mtls", "tls_mtls"), ("identity", "identity"),
                       ("secrets", "secrets"), ("access_control", "access_control")):
        v = getattr(args, name, None)
        if v is not None:
            upd[attr] = v
    if getattr(args, "listen", None):
        upd["listen"] = tuple(args.listen)
    if getattr(args, "connect", None):
        upd["connect"] = tuple(args.connect)
    opts = ZenohOptions(**{**base.__dict__, **upd})
    opts.validate()
    return opts


def build_config(opts: ZenohOptions) -> zenoh.Config:
    """The zenoh.Config for these options."""
    opts.validate()
    conf = zenoh.Config.from_file(opts.config_file) if opts.config_file else zenoh.Config()

    def put(key: str, value: object) -> None:
        conf.insert_json5(key, json.dumps(value))

    _put_links(opts, put)
    _put_tls(opts, put)
    if opts.access_control:
        conf.insert_json5("access_control", Path(opts.access_control).read_text())
    for key, value in opts.extra:
        conf.insert_json5(key, value)
    return conf


def _put_links(opts: ZenohOptions, put) -> None:
    """Mode, scouting, endpoints and shared memory."""
    put("mode", opts.mode)
    put("scouting/multicast/enabled", opts.multicast_scouting)
    if opts.listen:
        put("listen/endpoints", list(opts.listen))
    elif not opts.config_file and opts.mode == "peer":
        # Zenoh's default peer listens on every interface; stay on loopback unless asked.
        put("listen/endpoints", ["tcp/127.0.0.1:0"])
    if opts.connect:
        put("connect/endpoints", list(opts.connect))
    put("transport/shared_memory/enabled", bool(opts.shared_memory))
    if opts.shared_memory:
        put("transport/shared_memory/transport_optimization/pool_size", SHM_POOL_BYTES)


def _tls_files(opts: ZenohOptions, put) -> tuple[str | None, str | None, str | None, bool]:
    """(root CA, certificate, key, mutual TLS): the options', completed from the secrets folder;
    puts the user/password authentication of the secrets folder on the way."""
    root_ca, cert, key, mtls = opts.tls_root_ca, opts.tls_cert, opts.tls_key, opts.tls_mtls
    if not opts.secrets:
        return root_ca, cert, key, mtls
    from cinetransfer.shared import access

    sec = Path(opts.secrets)
    if opts.mode == "router":
        put("transport/auth/usrpwd/dictionary_file", str(sec / "users.txt"))
    if opts.identity:
        put("transport/auth/usrpwd/user", opts.identity)
        put("transport/auth/usrpwd/password", access.read_password(sec, opts.identity))
    if any(endpoint_host(ep)[0] in ("tls", "quic") for ep in (*opts.listen, *opts.connect)):
        root_ca = root_ca or str(sec / "ca.pem")
        if not cert and opts.identity and (sec / f"{opts.identity}.pem").is_file():
            cert, key = str(sec / f"{opts.identity}.pem"), str(sec / f"{opts.identity}-key.pem")
        mtls = True
    return root_ca, cert, key, mtls


def _put_tls(opts: ZenohOptions, put) -> None:
    root_ca, cert, key, mtls = _tls_files(opts, put)
    if root_ca:
        put("transport/link/tls/root_ca_certificate", root_ca)
    if cert:
        put("transport/link/tls/listen_certificate", cert)
        put("transport/link/tls/listen_private_key", key)
        put("transport/link/tls/connect_certificate", cert)
        put("transport/link/tls/connect_private_key", key)
    if mtls:
        put("transport/link/tls/enable_mtls", True)


def endpoint_host(endpoint: str) -> tuple[str, str]:
    """('tcp', '127.0.0.1') for 'tcp/127.0.0.1:7447' (IPv6 brackets and ?/# suffixes removed)."""
    proto, _, rest = endpoint.partition("/")
    rest = rest.split("?", 1)[0].split("#", 1)[0]
    host = rest.rsplit(":", 1)[0] if ":" in rest else rest
    return proto.lower(), host.strip("[]")


def _is_local(proto: str, host: str) -> bool:
    if proto.startswith("unix"):
        return True
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now (for a router or peer started next)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def open_session(opts: ZenohOptions) -> zenoh.Session:
    """Open a session; the caller must close it (use `with`)."""
    conf = build_config(opts)
    try:
        return zenoh.open(conf)
    except zenoh.ZError as e:
        if opts.connect and not (opts.identity and opts.secrets):
            raise zenoh.ZError(f"{e} — if this is a secure deployment, its router admits only an identity with "
                               f"its password: --identity NAME --secrets DIR, or deploy.join.open_as() "
                               f"(docs/security.md)") from None
        raise
