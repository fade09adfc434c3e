"""Result files written to a temporary name and renamed into place (STYLE §11).

A reader — a person, `cinetransfer transfer`, a second run — either sees the previous file or the
complete new one, never half of one: `os.replace` within one directory is atomic on POSIX and
Windows. The temporary name is unique (two writers of one path never share a temp file), lives
beside the target (same file system, so the rename cannot turn into a copy), and is removed when
the writing fails.

    with atomic_write("style.json") as fh:          # text; binary=True for bytes
        json.dump(d, fh)

    f = AtomicFile("measurements.msgpack", binary=True)   # streaming writers
    f.file.write(...)
    f.commit()                                            # or f.discard()
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Any, Iterator


class AtomicFile:
    """An open temporary file that becomes `path` on `commit()` and vanishes on `discard()`."""

    def __init__(self, path: str | os.PathLike, *, binary: bool = False, encoding: str = "utf-8",
                 mode: int | None = None) -> None:
        self.path = Path(path)
        self.mode = mode  # None: the usual permissions (umask applies); e.g. 0o600 for secrets
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent or ".")
        self.tmp_path = Path(tmp)
        self.file: IO[Any] = os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": encoding}))
        self.done = False

    def commit(self) -> None:
        """Flush to disk and rename into place (idempotent)."""
        if self.done:
            return
        self.done = True
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            # mkstemp creates 0600; a result file gets the usual permissions (umask applies)
            if self.mode is None:
                umask = os.umask(0)
                os.umask(umask)
                os.chmod(self.tmp_path, 0o666 & ~umask)
            else:
                os.chmod(self.tmp_path, self.mode)
            os.replace(self.tmp_path, self.path)
        except BaseException:
            self._remove()
            raise

    def discard(self) -> None:
        """Close and delete the temporary file; `path` is left as it was (idempotent)."""
        if self.done:
            return
        self.done = True
        self._remove()

    def _remove(self) -> None:
        with contextlib.suppress(OSError):
            self.file.close()
        with contextlib.suppress(FileNotFoundError):
            self.tmp_path.unlink()


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, *, binary: bool = False, encoding: str = "utf-8",
                 mode: int | None = None) -> Iterator[IO[Any]]:
    """Write `path` through a temporary file: renamed into place when the block ends normally,
    deleted (and `path` untouched) when it raises. `mode`: see AtomicFile."""
    f = AtomicFile(path, binary=binary, encoding=encoding, mode=mode)
    try:
        yield f.file
    except BaseException:
        f.discard()
        raise
    f.commit()
