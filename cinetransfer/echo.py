"""`cinetransfer echo RUN.mcap KEY`: a recorded channel's messages, one JSON line each.

KEY is a topic of the recording or a Zenoh key expression (`ct/transfer/health/*`,
`ct/**/state`). Each line is `{"t": seconds from the recording's start, "key": topic, "msg": ...}`:
our messages in their JSON form (the schema in docs/messages.md), Foxglove protobuf messages
(transforms, calibration, video) as protobuf JSON with their byte fields shown by length, and a
payload our codec could not decode by its length. `--start`/`--end` (seconds from the
recording's start) and `--limit` narrow it down.
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Iterator

import zenoh

from cinetransfer.runlog import RAW_ENCODING, RunFormatError, RunReader, _protobuf_class


def key_matcher(key: str) -> Any:
    """A predicate on topics: the exact topic, or those the key expression intersects."""
    try:
        expr = zenoh.KeyExpr(key)
    except zenoh.ZError as e:
        raise ValueError(f"{key!r} is not a key expression: {e}") from None
    return lambda topic: topic == key or _intersects(expr, topic)


def _intersects(expr: Any, topic: str) -> bool:
    try:
        return expr.intersects(zenoh.KeyExpr(topic))
    except zenoh.ZError:  # a recorded topic that is no valid key (derived names are): exact match only
        return False


def decoded(rec: Any, ch: Any, schema: Any, pb: dict[str, Any]) -> Any:
    """One stored message as plain JSON values."""
    if ch.message_encoding == "json":
        return json.loads(rec.data)
    if ch.message_encoding == "protobuf" and schema is not None:
        from google.protobuf.json_format import MessageToDict

        if schema.name not in pb:
            pb[schema.name] = _protobuf_class(schema)
        msg = pb[schema.name].FromString(rec.data)
        for f, v in msg.ListFields():
            if f.type == f.TYPE_BYTES:  # frames: say how big, never dump the image
                msg.ClearField(f.name)
                out = MessageToDict(msg, preserving_proto_field_name=True)
                out[f.name] = {"bytes": len(v)}
                return out
        return MessageToDict(msg, preserving_proto_field_name=True)
    return {"encoding": ch.message_encoding or RAW_ENCODING, "bytes": len(rec.data)}


def lines(run: RunReader, key: str, *, start: float = 0.0, end: float | None = None,
          limit: int = 0) -> Iterator[str]:
    match = key_matcher(key)
    t0 = run.info.start_ns
    pb: dict[str, Any] = {}
    n = 0
    for rec, ch, schema in run.records():
        t = (rec.log_time - t0) / 1e9
        if not match(ch.topic) or t < start:
            continue
        if end is not None and t > end:
            break
        yield json.dumps({"t": round(t, 6), "key": ch.topic, "msg": decoded(rec, ch, schema, pb)})
        n += 1
        if limit and n >= limit:
            return


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer echo", description=__doc__.splitlines()[0])
    p.add_argument("log", help="a recording (run.mcap)")
    p.add_argument("key", help="a topic or key expression (e.g. ct/transfer/vehicle/state, ct/*/health/**)")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="from S seconds after the recording's start")
    p.add_argument("--end", type=float, default=None, metavar="S", help="up to S seconds after the recording's start")
    p.add_argument("--limit", type=int, default=0, metavar="N", help="at most N messages (0 = all)")
    p.add_argument("--salvage", action="store_true", help="a recording cut inside a record: echo what comes before")
    args = p.parse_args(argv)
    try:
        run = RunReader(args.log, salvage=args.salvage)
        found = [t for t in run.info.channels if key_matcher(args.key)(t)]
        if not found:
            print(f"cinetransfer echo: no channel of {args.log} matches {args.key!r} (see `cinetransfer info`)",
                  file=sys.stderr)
            return 2
        for line in lines(run, args.key, start=args.start, end=args.end, limit=args.limit):
            sys.stdout.write(line + "\n")
    except (OSError, RunFormatError, ValueError) as e:
        print(f"cinetransfer echo: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `| head`: the reader has seen enough
        sys.stderr.close()
    return 0
