"""How a tool joins a running deployment as an identity: its router endpoint and secrets folder.

`deployment_options` is the one way for a tool (transfer, monitor, command senders) to join a
deployment; it finds the router and credentials the way `cinetransfer deploy` does.
"""
from __future__ import annotations

import os

import zenoh

from cinetransfer.deploy.config import load_config
from cinetransfer.deploy.rundir import resolve_run_dir
from cinetransfer.deploy.security import secrets_dir
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.zenoh_config import ZenohOptions, open_session


class NotRunningError(ValueError):
    """The deployment has never been brought up here: there are no credentials to join it with."""


def deployment_options(config: str | os.PathLike, identity: str = "operator", *,
                       run_dir: str | os.PathLike | None = None, **overrides: object) -> ZenohOptions:
    """Options to join the deployment `config` (a shipped name or a YAML path) as `identity`.

    Finds the deployment's router endpoint and secrets folder the way `cinetransfer deploy` does
    (`run_dir` as given to `deploy up --run-dir`, else the per-config state folder); `overrides`
    set further ZenohOptions fields, e.g. shared_memory=True. Identities: shared/access.py.
    """
    cfg = load_config(str(config))
    rd = resolve_run_dir(cfg, run_dir)
    if not cfg.check_endpoint:
        raise ValueError(f"deploy config {cfg.path} has no router endpoint to join")
    secrets = secrets_dir(cfg, rd)
    if cfg.secure and not (secrets / "users.txt").is_file():
        if not cfg.secrets:  # the folder 'deploy up' generates: never made, so never started here
            raise NotRunningError(f"deployment {cfg.name} is not running here: no credentials in {secrets} "
                                  f"('cinetransfer deploy up {cfg.name}' makes them)")
        raise ConfigError(f"secrets folder {secrets} has no users.txt (make one with "
                          "'cinetransfer deploy certs DIR --one-host')")
    base: dict[str, object] = {"mode": "client", "connect": (cfg.check_endpoint,), "identity": identity,
                               "secrets": str(secrets) if cfg.secure else None}
    opts = ZenohOptions(**{**base, **overrides})  # type: ignore[arg-type]
    opts.validate()
    return opts


def open_as(config: str | os.PathLike, identity: str = "operator", *, run_dir: str | os.PathLike | None = None,
            **overrides: object) -> zenoh.Session:
    """Open a session on the deployment `config` as `identity` (see deployment_options)."""
    return open_session(deployment_options(config, identity, run_dir=run_dir, **overrides))
