"""Accept a style as a file path or as an `Instructions` message (the report's only adapter).

Paths are read with the smoother's own loader (`shared/instructions.py`,
`load_style_file`), so the report refuses exactly what the rest of the project refuses.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Union

from cinetransfer.shared import messages as M
from cinetransfer.shared.instructions import load_style_file

StyleLike = Union[str, os.PathLike, M.Instructions, Any]


class StyleLoadError(ValueError):
    """A style could not be loaded; the message says which file and why."""


def load_style_any(style: StyleLike) -> tuple[M.Instructions, dict[str, Any]]:
    """(instructions, diagnostics) from a path, an Instructions, or anything with `.instructions`
    (the smoother's StyleFile / SmoothResult). Diagnostics are {} when there are none."""
    if isinstance(style, M.Instructions):
        return style, {}
    inner = getattr(style, "instructions", None)
    if isinstance(inner, M.Instructions):
        diag = getattr(style, "diagnostics", None)
        return inner, dict(diag) if isinstance(diag, dict) else {}
    if isinstance(style, (str, os.PathLike)):
        p = Path(style)
        try:
            sf = load_style_file(p)
        except ValueError as e:  # StyleFileError and codec errors are ValueErrors
            raise StyleLoadError(str(e)) from None
        return sf.instructions, dict(sf.diagnostics or {})
    raise TypeError(f"a style must be a path or an Instructions message, not {type(style).__name__}")
