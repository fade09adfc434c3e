"""Import a package whole, even when another thread imports beside it.

Two threads importing overlapping module graphs can meet Python's import-lock deadlock check, which
fails one of the imports part-way. The package itself then leaves sys.modules, but the submodules it
had already run stay there, each holding the failed package object: a later import of the package
succeeds, yet those submodules reach into the dead one (the report's truth floor failed on a loaded
machine with cvxpy's expression module asking the half-imported cvxpy for `promote`). So a failed
import forgets the whole package before anyone imports it again, and is tried again."""
from __future__ import annotations

import importlib
import sys
import threading
import types

ATTEMPTS = 3
#: one import_whole at a time: forgetting a package under another thread's import of it would split it in two
_LOCK = threading.RLock()


def import_whole(name: str, attempts: int = ATTEMPTS) -> types.ModuleType:
    """`name` imported; on a failure its package and every submodule are forgotten and the import is
    tried again, up to `attempts` times in all (the last failure is raised, with the package forgotten)."""
    with _LOCK:
        for attempt in range(attempts):
            try:
                return importlib.import_module(name)
            except Exception:
                forget(name)
                if attempt == attempts - 1:
                    raise
    raise ValueError(f"import_whole: attempts must be at least 1, got {attempts}")


def forget(name: str) -> None:
    """Remove the top-level package of `name` and all its submodules from sys.modules."""
    top = name.split(".")[0]
    for mod in [m for m in sys.modules if m == top or m.startswith(top + ".")]:
        sys.modules.pop(mod, None)
