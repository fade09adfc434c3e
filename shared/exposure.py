"""Who could reach a Zenoh session: the one rule every way of configuring Zenoh must pass.

Whatever set the session up (flags, `--zenoh-config FILE`, $CT_ZENOH_CONFIG, a deploy config),
the check runs on the *effective* configuration (what zenoh would actually be given), so a file
cannot open what the flags would have refused:

- a listener off loopback must be tls/ or quic/ with client certificates (mutual TLS);
- a peer stays on loopback: it enforces no access rules, so it neither listens on nor connects to
  another host, and does no multicast scouting (which connects to whatever answers on the LAN).

Anything off the host goes through a router, which authenticates and enforces shared/access.py.
"""
from __future__ import annotations

import ipaddress
import json
from dataclasses import dataclass

from cinetransfer.shared.errors import ConfigError

TLS_PROTOCOLS = ("tls", "quic")


@dataclass(frozen=True)
class Exposure:
    """The parts of a Zenoh configuration that decide who can connect."""

    mode: str
    listen: tuple[str, ...]
    connect: tuple[str, ...]
    mtls: bool
    multicast_scouting: bool


def endpoint_host(endpoint: str) -> tuple[str, str]:
    """('tcp', '127.0.0.1') for 'tcp/127.0.0.1:7447' (IPv6 brackets and ?/# suffixes removed)."""
    proto, _, rest = endpoint.partition("/")
    rest = rest.split("?", 1)[0].split("#", 1)[0]
    host = rest.rsplit(":", 1)[0] if ":" in rest else rest
    return proto.lower(), host.strip("[]")


def is_loopback(endpoint: str) -> bool:
    """True for an endpoint only this host can reach (unix sockets, localhost, 127.0.0.0/8, ::1)."""
    proto, host = endpoint_host(endpoint)
    if proto.startswith("unix") or host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a DNS name (or a wildcard like 0.0.0.0 handled above as an address)
        return False


def check(e: Exposure) -> None:
    """Raise a one-line ConfigError if `e` lets anyone off this host in unauthenticated."""
    for ep in e.listen:
        proto, host = endpoint_host(ep)
        if proto in TLS_PROTOCOLS and not e.mtls:
            raise ConfigError(f"listener {ep!r}: tls/quic listeners must require client certificates "
                              f"(--mtls, or --secrets DIR which implies it; docs/security.md)")
        if proto not in TLS_PROTOCOLS and not is_loopback(ep):
            where = f"[{host}]" if ":" in host else host
            raise ConfigError(f"listener {ep!r} would accept unauthenticated connections from the network; "
                              f"listen on 127.0.0.1 or use tls/{where}:PORT with mTLS (docs/security.md)")
    if e.mode != "peer":
        return
    off_host = [ep for ep in (*e.listen, *e.connect) if not is_loopback(ep)]
    if off_host:
        raise ConfigError(f"peer mode off loopback ({off_host[0]}): a peer enforces no access rules; use mode "
                          f"client with a router, or a router with mutual TLS (docs/security.md)")
    if e.multicast_scouting:
        raise ConfigError("peer mode with multicast scouting would connect to any peer on the network; use "
                          "explicit loopback endpoints or mode client (docs/security.md)")


def setting(conf, key: str):
    """The value at `key` of a zenoh.Config (None if unset or unknown)."""
    try:
        return json.loads(conf.get_json(key))
    except Exception:  # zenoh raises its own error type for a key it does not know
        return None


def _by_mode(value, mode: str) -> list:
    """Zenoh's mode-dependent values ({"router": [...], "peer": [...]}) resolved for `mode`."""
    if isinstance(value, dict):
        value = value.get(mode)
    return list(value or [])


def of_config(conf) -> Exposure:
    """What a `zenoh.Config` exposes, with Zenoh's own defaults where it leaves a key unset."""
    mode = setting(conf, "mode") or "peer"
    multicast = setting(conf, "scouting/multicast/enabled")
    if isinstance(multicast, dict):
        multicast = multicast.get(mode)
    return Exposure(mode=mode, listen=tuple(_by_mode(setting(conf, "listen/endpoints"), mode)),
                    connect=tuple(_by_mode(setting(conf, "connect/endpoints"), mode)),
                    mtls=bool(setting(conf, "transport/link/tls/enable_mtls")),
                    multicast_scouting=True if multicast is None else bool(multicast))  # Zenoh's default: on
