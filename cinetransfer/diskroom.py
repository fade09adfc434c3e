"""Disk room held for a file to close into: blocks allocated past its end (Linux `fallocate` with
FALLOC_FL_KEEP_SIZE), so its size, and what a reader sees, stay as they are.

Room freed back to the disk (a reserve file deleted on a write error) goes to whichever writer
comes first: on a loaded machine another writer that was filling the disk took the recorder's
freed reserve before run.mcap had closed into it, and a write that ran into the full disk cut a
record in half. Blocks a file holds past its end are its own: its later writes land in them
whatever else fills the disk. `hold` again after the file has grown keeps the room ahead of it;
`release` gives back what is left.
"""
from __future__ import annotations

import ctypes
import errno
import os
from typing import Any

_KEEP_SIZE = 0x01  # FALLOC_FL_KEEP_SIZE (linux/falloc.h)
_fallocate: Any = None  # the C function, looked up on first use; False: this system has none


def _function() -> Any:
    global _fallocate
    if _fallocate is None:
        try:
            f = ctypes.CDLL(None, use_errno=True).fallocate64
        except (OSError, AttributeError):  # not glibc/Linux
            _fallocate = False
        else:
            f.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
            f.restype = ctypes.c_int
            _fallocate = f
    return _fallocate


def hold(fd: int, nbytes: int, *, at: int | None = None, name: str | None = None) -> bool:
    """Keep `nbytes` allocated past byte `at` (default: the end) of the open file `fd`, its size
    unchanged. True: held; False: this system or file system cannot (nothing was done); OSError
    (ENOSPC) when the disk has not that much room left: nothing was written, the file is intact."""
    f = _function()
    if not f:
        return False
    start = os.fstat(fd).st_size if at is None else at
    if f(fd, _KEEP_SIZE, start, nbytes) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EOPNOTSUPP, errno.ENOSYS):
        return False
    raise OSError(err, os.strerror(err), name)


def release(fd: int) -> None:
    """Give back the room held past the end of `fd` (truncating to its own size frees it)."""
    os.ftruncate(fd, os.fstat(fd).st_size)


def allocated(path: str | os.PathLike) -> int:
    """Bytes the disk has given the file at `path` (held room included)."""
    return os.stat(path).st_blocks * 512
