"""Zenoh session configuration from a file, the environment and command-line flags.

Precedence (lowest first): safe defaults → a JSON5 config file (`--zenoh-config` or
$CT_ZENOH_CONFIG) → flags. Defaults differ from Zenoh's own on purpose: multicast scouting is
OFF (a peer would otherwise announce itself on every interface) and a peer listens on
127.0.0.1 only unless told otherwise.
"""
from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass, field

import zenoh

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
    extra: tuple[tuple[str, str], ...] = field(default=())  # (key, json5 value) pairs

    def validate(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"zenoh mode {self.mode!r} is not one of {', '.join(MODES)}")
        for ep in (*self.listen, *self.connect):
            if "/" not in ep:
                raise ValueError(f"zenoh endpoint {ep!r} must look like 'tcp/127.0.0.1:7447'")
        for p in (self.config_file, self.tls_root_ca, self.tls_cert, self.tls_key):
            if p and not os.path.isfile(p):
                raise ValueError(f"zenoh configuration file {p!r} does not exist")
        if bool(self.tls_cert) != bool(self.tls_key):
            raise ValueError("--tls-cert and --tls-key must be given together")


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


def options_from_args(args: argparse.Namespace, **defaults: object) -> ZenohOptions:
    """Build options: `defaults` (e.g. from a deploy config), then flags on top."""
    base = ZenohOptions(**defaults)  # type: ignore[arg-type]
    upd: dict[str, object] = {}
    cfg = getattr(args, "zenoh_config", None) or os.environ.get(ENV_CONFIG) or base.config_file
    if cfg:
        upd["config_file"] = cfg
    for name, attr in (("mode", "mode"), ("multicast_scouting", "multicast_scouting"),
                       ("shm", "shared_memory"), ("tls_root_ca", "tls_root_ca"), ("tls_cert", "tls_cert"),
                       ("tls_key", "tls_key"), ("mtls", "tls_mtls")):
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
    if opts.tls_root_ca:
        put("transport/link/tls/root_ca_certificate", opts.tls_root_ca)
    if opts.tls_cert:
        put("transport/link/tls/listen_certificate", opts.tls_cert)
        put("transport/link/tls/listen_private_key", opts.tls_key)
        put("transport/link/tls/connect_certificate", opts.tls_cert)
        put("transport/link/tls/connect_private_key", opts.tls_key)
    if opts.tls_mtls:
        put("transport/link/tls/enable_mtls", True)
    for key, value in opts.extra:
        conf.insert_json5(key, value)
    return conf


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now (for a router or peer started next)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def open_session(opts: ZenohOptions) -> zenoh.Session:
    """Open a session; the caller must close it (use `with`)."""
    return zenoh.open(build_config(opts))
