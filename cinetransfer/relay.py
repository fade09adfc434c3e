"""`cinetransfer relay`: forward validated messages from one key expression to another key.

Useful to copy a topic between rigs (e.g. replayed instructions into a live rig) and as the
smallest complete node: it decodes every input (rejecting and counting malformed payloads or
wrong schema versions in its Health), re-encodes and republishes.
"""
from __future__ import annotations

import argparse

from cinetransfer.shared import codec, nodeconfig
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.node import add_node_arguments, node_from_args


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer relay", description=__doc__.splitlines()[0])
    p.add_argument("--from", dest="src", required=True, metavar="KEYEXPR", help="key expression to read")
    p.add_argument("--to", dest="dst", required=True, metavar="KEY", help="key to publish on")
    p.add_argument("--name", default="relay", help="node name (default %(default)s)")
    p.add_argument("--queue", type=int, default=64, help="input queue length (drop-oldest)")
    p.add_argument("--no-drop", action="store_true",
                   help="block rather than drop when the link is congested (default: the destination key's "
                        "policy from the dataflow; drop for a key outside it)")
    add_node_arguments(p)
    nodeconfig.add_config_arguments(p, "relay")
    try:
        args = nodeconfig.parse_with_settings(p, argv, "relay")
    except ConfigError as e:
        return report_config_error(e, "cinetransfer relay")
    try:
        node = node_from_args(args.name, args, config=vars(args))
    except ValueError as e:
        p.error(str(e))
    with node:
        inbox = node.subscribe(args.src, maxlen=args.queue, policy="drop-oldest")
        pub = node.publisher(args.dst, block=True if args.no_drop else None)
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
