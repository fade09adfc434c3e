"""Where cinetransfer keeps caches: the one place that reads $CT_CACHE_DIR."""
from __future__ import annotations

import os
from pathlib import Path

ENV_CACHE = "CT_CACHE_DIR"


def cache_dir(*parts: str) -> Path:
    """$CT_CACHE_DIR, else $XDG_CACHE_HOME/cinetransfer, else ~/.cache/cinetransfer; `parts` appended."""
    env = os.environ.get(ENV_CACHE)
    if env:
        base = Path(env)
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "cinetransfer"
    return base.joinpath(*parts)
