"""Where the bundled real clips are (../shared/data beside the repository, or $CT_DATA_DIR)."""
from __future__ import annotations

import os
from pathlib import Path

ENV = "CT_DATA_DIR"


def data_dir() -> Path:
    """The folder of real clips: $CT_DATA_DIR, else ../shared/data beside the source checkout,
    else ../shared/data from the working directory. Raises FileNotFoundError naming the fix."""
    env = os.environ.get(ENV)
    candidates = [Path(env)] if env else [Path(__file__).resolve().parents[1].parent / "shared" / "data",
                                          Path.cwd().parent / "shared" / "data"]
    for d in candidates:
        if d.is_dir():
            return d
    raise FileNotFoundError(f"real data folder not found (looked in {', '.join(map(str, candidates))}): "
                            f"set {ENV}")

