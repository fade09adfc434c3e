"""The project's error base and its one configuration error.

Every node, tool and library part raises `ConfigError` for a bad setting; a command's `main`
reports it with `report_config_error` (stderr, exit status 2, the message names the field).
"""
from __future__ import annotations

import sys

#: exit status of a command refused for a bad configuration (argparse uses 2 for bad flags too)
EXIT_CONFIG = 2


class CinetransferError(Exception):
    """Base of the errors cinetransfer raises on purpose."""


class ConfigError(CinetransferError, ValueError):
    """A setting is invalid; the message names the field and what is allowed.

    A ValueError too, so that callers that validated numbers with `except ValueError` still see it.
    """


def report_config_error(err: ConfigError, prog: str) -> int:
    """Print `prog: config error: <message>` on stderr; return the exit status to use (2)."""
    print(f"{prog}: config error: {err}", file=sys.stderr)
    return EXIT_CONFIG
