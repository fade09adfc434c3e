"""The `cinetransfer` command: one console script, one subcommand per job.

Subcommands are registered lazily (module path + function) so that `cinetransfer --help`
stays fast and a service's heavy imports (torch, mediapipe, casadi) load only when used.
Each target is `main(argv: list[str]) -> int`.

Exit codes, for every command: 0 done; 1 an error (one line on stderr: a file that cannot be
written, no deployment to talk to, ...); 2 a bad command line; 130 interrupted. `transfer` adds 3
(a degraded take, docs/transfer.md). No user's mistake prints a traceback; CT_DEBUG=1 shows it.
"""
from __future__ import annotations

import errno
import importlib
import os
import re
import sys

from cinetransfer.shared.errors import ConfigError, report_config_error

#: name -> (module, function, one-line help)
COMMANDS: dict[str, tuple[str, str, str]] = {
    # services (long-running Zenoh nodes)
    "detector": ("cinetransfer.services.detector.service", "main", "run the detector node"),
    "smoother": ("cinetransfer.services.smoother.service", "main", "run the smoother node"),
    "planner": ("cinetransfer.services.planner.service", "main", "run the planner (MPC) node"),
    "autopilot_bridge": ("cinetransfer.services.autopilot_bridge.service", "main",
                         "run the vehicle bridge node (built-in simulator or MAVLink)"),
    "source": ("cinetransfer.services.source.service", "main",
               "play a source clip into the dataflow (frames never dropped)"),
    "camera": ("cinetransfer.services.autopilot_bridge.camera_node", "main",
               "publish frames from a video device, file or RTSP URL"),
    "sim-vehicle": ("cinetransfer.services.autopilot_bridge.sim_vehicle", "main",
                    "a simulated vehicle behind a real MAVLink endpoint"),
    # tools
    "deploy": ("cinetransfer.deploy.cli", "main", "start/stop/inspect a set of nodes from a config"),
    "monitor": ("cinetransfer.monitor", "main", "live table of keys, rates and alive nodes"),
    "relay": ("cinetransfer.relay", "main", "forward validated messages from one key to another"),
    "router": ("cinetransfer.router", "main", "run a Zenoh router"),
    "detect": ("cinetransfer.services.detector.cli", "main", "measure a video: people, joints, focus"),
    "smooth": ("cinetransfer.services.smoother.cli", "smooth_main", "measurements -> style.json"),
    "extract": ("cinetransfer.extract", "main", "video -> style.json (detect + smooth)"),
    "plot": ("cinetransfer.services.smoother.cli", "plot_main", "plot a style.json"),
    "plan": ("cinetransfer.plan", "main", "fly a style.json in the simulator, in-process"),
    "transfer": ("cinetransfer.transfer", "main", "source video -> recorded shot + fidelity report"),
    "command": ("cinetransfer.command", "main", "send one command (play, start, stop, hold, ...) as the operator"),
    "replay": ("cinetransfer.replay", "main", "republish a recorded run on Zenoh"),
    "info": ("cinetransfer.runinfo", "main", "summarise a recording: channels, counts, rates, takes"),
    "echo": ("cinetransfer.echo", "main", "print a recorded channel's messages as JSON lines"),
    "record": ("cinetransfer.record", "main", "record live keys of a running rig into an MCAP file"),
    "rerun": ("cinetransfer.rerun_export", "main", "export a recording's plottable values to Rerun (.rrd)"),
    "report": ("cinetransfer.report.cli", "main", "build a fidelity report from a run folder"),
    "docs": ("cinetransfer.docgen", "main", "generate docs/messages.md from the schemas"),
}


def _usage() -> str:
    lines = ["usage: cinetransfer COMMAND [ARGS...]", "", "commands:"]
    for name, (_, _, help_) in COMMANDS.items():
        lines.append(f"  {name:<17} {help_}")
    lines.append("")
    lines.append("Run 'cinetransfer COMMAND --help' for a command's options.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:  # a command is required: say so, and fail like any other bad command line
        print(_usage(), file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if argv[0] == "--version":
        from cinetransfer import __version__

        print(__version__)
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"cinetransfer: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    mod_name, fn_name, _ = COMMANDS[name]
    try:
        mod = importlib.import_module(mod_name)
    except ModuleNotFoundError as e:
        if e.name and e.name.startswith("cinetransfer"):
            print(f"cinetransfer: command {name!r} is not available in this build ({e.name} missing)",
                  file=sys.stderr)
            return 2
        raise
    return _run(name, getattr(mod, fn_name), rest)


def _run(name: str, fn, rest: list[str]) -> int:
    """Run a command; what the user's environment got wrong is one line and an exit code, not a traceback."""
    try:
        return int(fn(rest) or 0)
    except KeyboardInterrupt:
        print(f"cinetransfer {name}: interrupted", file=sys.stderr)
        return 130
    except ConfigError as e:  # a bad setting found past a command's own checks: one line, exit 2
        return report_config_error(e, f"cinetransfer {name}")
    except Exception as e:  # noqa: BLE001 - filtered below: only the user-facing kinds become one line
        line = user_error(e)
        if line is None or os.environ.get("CT_DEBUG"):
            raise
        print(f"cinetransfer {name}: {line}", file=sys.stderr)
        return 1


def user_error(e: BaseException) -> str | None:
    """One line for an error of the user's environment (a file system refusal, no deployment to talk
    to); None for anything else (a bug: its traceback is worth seeing)."""
    if isinstance(e, OSError):
        what = e.strerror or errno.errorcode.get(e.errno or 0, "") or str(e)
        where = f": {e.filename}" if e.filename else ""
        return f"{what}{where}"
    if type(e).__name__ == "ZError" and type(e).__module__.split(".")[0] == "zenoh":
        said = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", str(e))  # (where in Zenoh's Rust source: no help to a user)
        return (f"cannot use the bus: {said} (is the deployment running and reachable? "
                "see 'cinetransfer deploy status CONFIG')")
    return None


if __name__ == "__main__":
    sys.exit(main())
