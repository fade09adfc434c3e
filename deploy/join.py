"""Join a running deployment as one identity: its router endpoint and secrets, found the way
`cinetransfer deploy` finds them. Tools (monitor, command, the transfer job) open their sessions
here; it sits above shared/ because it reads deploy configs (docs/security.md).
"""
from __future__ import annotations

import os

import zenoh

from cinetransfer.deploy import supervisor
from cinetransfer.shared import zenoh_config


def deployment_options(config: str | os.PathLike, identity: str = "operator", *,
                       run_dir: str | os.PathLike | None = None, **overrides: object) -> zenoh_config.ZenohOptions:
    """Options to join the deployment `config` (a shipped name or a YAML path) as `identity`.

    Finds the deployment's router endpoint and secrets folder the way `cinetransfer deploy` does
    (`run_dir` as given to `deploy up --run-dir`, else the per-config state folder); `overrides`
    set further ZenohOptions fields, e.g. shared_memory=True. Identities: shared/access.py.
    """
    cfg = supervisor.load_config(str(config))
    rd = supervisor.resolve_run_dir(cfg, run_dir)
    if not cfg.check_endpoint:
        raise ValueError(f"deploy config {cfg.path} has no router endpoint to join")
    base: dict[str, object] = {"mode": "client", "connect": (cfg.check_endpoint,), "identity": identity,
                               "secrets": str(supervisor.secrets_dir(cfg, rd)) if cfg.secure else None}
    opts = zenoh_config.ZenohOptions(**{**base, **overrides})  # type: ignore[arg-type]
    opts.validate()
    return opts


def open_as(config: str | os.PathLike, identity: str = "operator", *, run_dir: str | os.PathLike | None = None,
            **overrides: object) -> zenoh.Session:
    """Open a session on the deployment `config` as `identity` (see deployment_options)."""
    return zenoh_config.open_session(deployment_options(config, identity, run_dir=run_dir, **overrides))
