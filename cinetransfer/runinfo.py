"""`cinetransfer info RUN.mcap`: what a recording holds, at a glance.

Channels with their schema, encoding, message count and rate; the recording's duration (wall
clock, from its log times) and its flight time (camera frames x their period); and the takes,
read from the planner's start and stop commands. `--json` prints the same as one JSON object.
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from cinetransfer.runlog import RunFormatError, RunReader

COMMAND_SCHEMA = "cinetransfer.Command"


def channel_rate(ch: dict[str, Any]) -> float:
    """Messages per second over the channel's own span of log times (0 with fewer than 2)."""
    span = (ch["last_ns"] - ch["first_ns"]) / 1e9
    return (ch["count"] - 1) / span if ch["count"] > 1 and span > 0 else 0.0


def takes(run: RunReader) -> list[dict[str, Any]]:
    """The takes: each planner `start` command opens one (its instruction frames and pre-roll),
    the next `stop` or `start` closes it; times in seconds from the recording's first message."""
    out: list[dict[str, Any]] = []
    t0 = run.info.start_ns
    for rec, ch, schema in run.records():
        if schema is None or schema.name != COMMAND_SCHEMA or not ch.topic.endswith("/planner/command"):
            continue
        try:
            cmd = json.loads(rec.data)
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue
        t = round((rec.log_time - t0) / 1e9, 3)
        if out and out[-1]["end_s"] is None and cmd.get("action") in ("start", "stop"):
            out[-1]["end_s"] = t
        if cmd.get("action") == "start":
            args = cmd.get("args") or {}
            out.append({"start_s": t, "end_s": None, "first_frame": args.get("start_frame"),
                        "end_frame": args.get("end_frame"), "preroll_s": args.get("preroll_s")})
    return out


def summary(run: RunReader) -> dict[str, Any]:
    info = run.info
    channels = {topic: {"schema": c["schema"], "encoding": c["encoding"], "count": c["count"],
                        "rate_hz": round(channel_rate(c), 2)} for topic, c in sorted(info.channels.items())}
    return {"file": str(info.path), "bytes": info.bytes, "complete": info.complete, "meta": info.meta,
            "messages": info.messages, "duration_s": round(info.duration_s(), 3),
            "flight_s": round(info.flight_s(), 3), "camera_frames": info.frames, "takes": takes(run),
            "channels": channels}


def render(s: dict[str, Any]) -> str:
    meta = s["meta"]
    about = ", ".join(f"{k} {meta[k]}" for k in ("source", "scene", "rig", "keyexpr") if meta.get(k))
    lines = [f"file:      {s['file']} ({s['bytes'] / 1e6:.2f} MB, "
             f"{'complete' if s['complete'] else 'interrupted: no summary'})",
             f"recorded:  {meta.get('started', '?')}{' — ' + about if about else ''}",
             f"duration:  {s['duration_s']:.2f} s (wall clock); flight {s['flight_s']:.2f} s "
             f"({s['camera_frames']} camera frames)",
             f"messages:  {s['messages']}",
             f"takes:     {len(s['takes'])}"]
    for i, t in enumerate(s["takes"], 1):
        end = f"{t['end_s']:.2f} s" if t["end_s"] is not None else "the end"
        lines.append(f"  take {i}: {t['start_s']:.2f} s to {end}, instruction frames {t['first_frame']}.."
                     f"{t['end_frame']}, pre-roll {t['preroll_s']} s")
    lines.append(f"channels:  {len(s['channels'])}")
    width = max((len(t) for t in s["channels"]), default=5)
    lines.append(f"  {'topic':<{width}}  {'schema':<28} {'encoding':<9} {'count':>6} {'rate/s':>7}")
    for topic, c in s["channels"].items():
        lines.append(f"  {topic:<{width}}  {c['schema'] or '-':<28} {c['encoding']:<9} {c['count']:>6} "
                     f"{c['rate_hz']:>7.1f}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer info", description=__doc__.splitlines()[0])
    p.add_argument("log", help="a recording (run.mcap)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--salvage", action="store_true", help="a recording cut inside a record: describe what comes "
                                                           "before the cut instead of refusing")
    args = p.parse_args(argv)
    try:
        s = summary(RunReader(args.log, salvage=args.salvage))
    except (OSError, RunFormatError) as e:
        print(f"cinetransfer info: {e}", file=sys.stderr)
        return 2
    print(json.dumps(s, indent=1) if args.json else render(s))
    return 0
