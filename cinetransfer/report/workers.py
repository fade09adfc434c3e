"""A second process for the report's figures, so that they are drawn on the other core while this
process makes the side-by-side video, the floor and the page.

matplotlib holds the GIL while it draws, so a thread would not overlap it with the rest of the
report; a process does. It is started ahead (`FigureWorker()` while the take is filmed) and
imports matplotlib then, so the report pays neither the start nor the import. The figures are the
same bytes wherever they are drawn (one matplotlib, default settings, no pyplot state).
"""
from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
from typing import Any, Callable

log = logging.getLogger("cinetransfer.report")

#: the longest wait for one figure's result; the figures are awaited one after the other, so each
#: wait starts when the figure before it is in: a loaded machine has this long per figure. Past it
#: the process hangs, and the figure is drawn in this process instead
FIGURE_WAIT_S = 600.0

#: imported by the worker as it starts (what drawing a figure needs)
WARM = ("matplotlib.figure", "matplotlib.backends.backend_agg", "cinetransfer.report.figures",
        "cinetransfer.report.camera_motion")


def _start_worker() -> None:
    import importlib
    import signal

    # a Ctrl-C reaches the whole process group: the transfer decides what stops, and stops this
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for name in WARM:
        importlib.import_module(name)


class FigureWorker:
    """One worker process (spawned: no thread or lock of this process is copied into it). `submit`
    returns a Future, or None once the worker is unusable (the caller then draws in-process)."""

    def __init__(self) -> None:
        self._pool: cf.ProcessPoolExecutor | None = cf.ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker)
        self._pool.submit(int)  # start it (and its imports) now, not at the first figure

    def submit(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> cf.Future | None:
        if self._pool is None:
            return None
        try:
            return self._pool.submit(fn, *args, **kwargs)
        except (RuntimeError, cf.BrokenExecutor) as e:  # shut down, or its process died
            log.warning("figure process unusable (%s): figures are drawn in this process", e)
            return None

    def close(self, wait: bool = False) -> None:
        """Stop the worker (figures still being drawn are abandoned); `wait`: until its process has
        ended (then this process's CPU times include it: os.times() counts ended children)."""
        if self._pool is not None:
            self._pool.shutdown(wait=wait, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> "FigureWorker":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
