"""The MAVLink 2 signing key: one secret shared by the vehicle, the bridge and the ground station.

A file of 64 hexadecimal characters (the 32-byte secret), written 0600 by `cinetransfer deploy
certs` beside the other secrets. MAVLink 2 signs every message with it (SHA-256 over the secret,
the message and a timestamp, so a replayed message is refused too); docs/mavlink.md.
"""
from __future__ import annotations

import os
import secrets
from pathlib import Path

from cinetransfer.shared.atomic import atomic_write
from cinetransfer.shared.errors import ConfigError

KEY_FILE = "mavlink-signing.key"
KEY_BYTES = 32


def write_signing_key(folder: str | os.PathLike) -> Path:
    """A new random key in `folder`/KEY_FILE (mode 0600); returns its path."""
    path = Path(folder) / KEY_FILE
    with atomic_write(path, mode=0o600) as f:
        f.write(secrets.token_hex(KEY_BYTES) + "\n")
    return path


def read_signing_key(path: str | os.PathLike) -> bytes:
    """The 32-byte secret of a key file; ConfigError naming the file when it is not one."""
    try:
        text = Path(path).read_text().strip()
    except OSError as e:
        raise ConfigError(f"mavlink signing key {path}: cannot be read ({e.strerror})") from None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise ConfigError(f"mavlink signing key {path}: must hold {2 * KEY_BYTES} hexadecimal characters "
                          f"(create one with 'cinetransfer deploy certs DIR')")
    return key
