"""A secure deployment's credentials and the flags that make each process use them.

Secure by default (docs/security.md): unless the config says `security: {enabled: false}`,
every process joins the router as an identity with a password, the router enforces the
access-control rules of shared/access.py, and tls/ links use mutual TLS. The credentials come
from `security.secrets` ($CT_SECRETS in the shipped configs) or are generated on the first `up`
into RUN_DIR/secrets (0700). `cinetransfer deploy certs DIR` creates them for a split deployment.
"""
from __future__ import annotations

import json
from pathlib import Path

from cinetransfer.deploy.config import DeployConfig, Proc
from cinetransfer.deploy.rundir import write_atomic
from cinetransfer.shared.errors import ConfigError


def secrets_dir(cfg: DeployConfig, run_dir: Path) -> Path:
    return Path(cfg.secrets) if cfg.secrets else run_dir / "secrets"


def identities(cfg: DeployConfig) -> list[str]:
    from cinetransfer.shared import access

    return list(dict.fromkeys([*(p.identity for p in cfg.procs if p.identity), *access.TOOL_IDENTITIES,
                               *(g for g, _ in cfg.grants)]))


def prepare_security(cfg: DeployConfig, run_dir: Path) -> None:
    """Credentials (generated into RUN_DIR/secrets unless the config names a folder) and ACL files."""
    if not cfg.secure:
        return
    from cinetransfer.deploy import certs
    from cinetransfer.shared import access

    sec = secrets_dir(cfg, run_dir)
    from cinetransfer.shared.exposure import endpoint_host

    links = [ep for r in cfg.routers for i, ep in enumerate(r.argv) if i and r.argv[i - 1] in ("--listen", "--connect")
             and endpoint_host(ep)[0] in ("tls", "quic")]
    if links and cfg.secrets is None:
        raise ConfigError(f"this deployment links hosts over TLS ({', '.join(links)}); the hosts need credentials "
                          f"of one CA: run 'cinetransfer deploy certs DIR --host <drone address>', copy DIR/onboard "
                          f"to the drone and set CT_SECRETS=DIR/ground or DIR/onboard (docs/security.md)")
    if cfg.secrets is None:
        certs.ensure(sec, users=identities(cfg))
    elif not (sec / certs.USERS_FILE).is_file():
        raise ConfigError(f"security.secrets: {sec} has no {certs.USERS_FILE}; create it with "
                          f"'cinetransfer deploy certs {sec}'")
    for ident in identities(cfg):
        try:
            access.read_password(sec, ident)
        except ValueError as e:
            raise ConfigError(f"security: {e}") from None
    acl = access.access_control(grants={k: list(v) for k, v in cfg.grants})
    for r in cfg.routers:
        write_atomic(run_dir / f"{r.name}.acl.json", json.dumps(acl, indent=1))



def security_flags(cfg: DeployConfig, run_dir: Path, proc: Proc) -> list[str]:
    """Flags that make `proc` join as its identity (and a router enforce the rules)."""
    if not cfg.secure:
        return []
    flags = ["--secrets", str(secrets_dir(cfg, run_dir))]
    if proc.identity:
        flags += ["--identity", proc.identity]
    if proc.kind == "router":
        flags += ["--access-control", str(run_dir / f"{proc.name}.acl.json")]
    return flags
