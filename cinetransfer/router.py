"""`cinetransfer router`: a Zenoh router as a Python process.

No zenohd binary can be installed from PyPI; a session opened with mode "router" is a
working router (DESIGN §5). It listens where told (default tcp/127.0.0.1:7447), routes between
peers/clients, and exits cleanly on SIGINT/SIGTERM.
"""
from __future__ import annotations

import argparse
import logging
import sys

from cinetransfer.shared import zenoh_config
from cinetransfer.shared.node import setup_logging
from cinetransfer.shared.stopsignal import StopSignal

log = logging.getLogger("cinetransfer.router")


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer router", description=__doc__.splitlines()[0])
    p.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    zenoh_config.add_arguments(p)
    args = p.parse_args(argv)
    setup_logging(args.log_level)
    try:
        opts = zenoh_config.options_from_args(args, mode="router", listen=("tcp/127.0.0.1:7447",))
    except ValueError as e:
        print(f"cinetransfer router: config error: {e}", file=sys.stderr)
        return 2
    stop = StopSignal().install()  # a handler that sets an Event can deadlock (stopsignal.py)
    with zenoh_config.open_session(opts) as session:
        log.info("router %s listening on %s", session.info.zid(), ", ".join(opts.listen) or "(config file)")
        stop.wait()
    log.info("router stopped")
    return 0
