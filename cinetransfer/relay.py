"""`cinetransfer relay`: forward validated messages from one key expression to another key.

Useful to copy a topic between rigs (e.g. replayed instructions into a live rig) and as the
smallest complete node: it decodes every input (rejecting and counting malformed payloads or
wrong schema versions in its Health), re-encodes and republishes.
"""
from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from typing import ClassVar

from cinetransfer.shared import codec, nodeconfig
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.node import add_node_arguments, node_from_args
from cinetransfer.shared.nodeconfig import setting

NODE = "relay"


@dataclass(frozen=True)
class RelayConfig:
    """The relay's settings (shared/nodeconfig.py): defaults, then `--config`, then flags."""

    #: the keys settings files wrote before (named like the flags; `from` is a Python keyword)
    SETTING_ALIASES: ClassVar[dict[str, str]] = {"from": "from_key", "to": "to_key", "src": "from_key",
                                                 "dst": "to_key", "no-drop": "no_drop"}

    from_key: str = setting("", flag="--from", metavar="KEYEXPR", help="key expression to read (required)")
    to_key: str = setting("", flag="--to", metavar="KEY", help="key to publish on (required)")
    name: str = setting("relay", flag="--name", metavar="NAME", help="node name")
    queue: int = setting(64, flag="--queue", range=">= 1", metavar="N", help="input queue length (drop-oldest)")
    no_drop: bool = setting(False, flag="--no-drop",
                            help="block rather than drop when the link is congested (default: the destination "
                                 "key's policy from the dataflow; drop for a key outside it)")



def build_parser() -> argparse.ArgumentParser:
    p = nodeconfig.settings_parser(RelayConfig, NODE, "cinetransfer relay", __doc__.splitlines()[0])
    add_node_arguments(p)
    return p


def config_from_args(args: argparse.Namespace) -> RelayConfig:
    """Defaults, then the settings (`--config`), then the flags; both keys must be given by then."""
    cfg = nodeconfig.config_from_args(RelayConfig, args, NODE)
    for name, flag in (("from_key", "--from"), ("to_key", "--to")):
        if not getattr(cfg, name):
            raise ConfigError(f"{NODE} config: {name} ({flag}) is required")
    return cfg


def main(argv: list[str]) -> int:
    p = build_parser()
    args = p.parse_args(argv)
    try:
        cfg = config_from_args(args)
        node = node_from_args(cfg.name, args, config=dataclasses.asdict(cfg))
    except ConfigError as e:
        return report_config_error(e, "cinetransfer relay")
    except ValueError as e:  # a bad bus option (--connect, ...)
        p.error(str(e))
    with node:
        inbox = node.subscribe(cfg.from_key, maxlen=cfg.queue, policy="drop-oldest")
        pub = node.publisher(cfg.to_key, block=True if cfg.no_drop else None)
        node.ready()
        while node.running:
            msg = inbox.get(timeout=0.2)
            if msg is None:
                continue
            with node.timed():
                try:
                    pub.put(msg)
                except codec.EncodeError as e:
                    node.reject(f"cannot re-encode: {e}")
    return 0
