"""`cinetransfer command TARGET ACTION [NAME=VALUE ...]`: send one command as the operator.

    cinetransfer command source play path=/data/clip.mp4 stop=120
    cinetransfer command planner start preroll_s=3
    cinetransfer command planner stop
    cinetransfer command vehicle hold

TARGET is source, smoother, planner or vehicle (the bridge). It joins a running deployment
(`--deployment`, default local) as the 'operator' identity, the only one the access rules let
send commands, publishes the Command once and exits. VALUEs are read as int, float, true/false,
or else text.
"""
from __future__ import annotations

import argparse
import sys
import time

from cinetransfer.deploy import join
from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M

TARGETS = {"source": keys.SOURCE_COMMAND, "smoother": keys.SMOOTHER_COMMAND, "planner": keys.PLANNER_COMMAND,
           "vehicle": keys.BRIDGE_COMMAND}


def parse_value(text: str) -> bool | int | float | str:
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_args_kv(items: list[str]) -> dict:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ValueError(f"argument {item!r} must look like NAME=VALUE")
        out[name] = parse_value(value)
    return out


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer command", description=__doc__.splitlines()[0],
                                epilog="\n".join(__doc__.splitlines()[2:]),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("target", choices=sorted(TARGETS))
    p.add_argument("action")
    p.add_argument("args", nargs="*", metavar="NAME=VALUE")
    p.add_argument("--rig", default="rig0", help="rig (default %(default)s)")
    p.add_argument("--deployment", default="local", help="running deployment to join (default %(default)s)")
    a = p.parse_args(argv)
    try:
        cmd_args = parse_args_kv(a.args)
        opts = join.deployment_options(a.deployment, "operator")
    except join.NotRunningError as e:
        print(f"cinetransfer command: {e}", file=sys.stderr)
        return 1
    except ValueError as e:
        print(f"cinetransfer command: {e}", file=sys.stderr)
        return 2
    cmd = M.Command(stamp_ns=M.now_ns(), action=a.action, args=cmd_args)
    with zenoh_config.open_session(opts) as session:
        pub = session.declare_publisher(TARGETS[a.target].key(a.rig))
        time.sleep(0.3)  # let the router learn the subscribers before the one message goes
        pub.put(codec.encode(cmd))
        time.sleep(0.2)
        pub.undeclare()
    print(f"sent {a.action} {cmd_args or ''} to {TARGETS[a.target].key(a.rig)}")
    return 0
