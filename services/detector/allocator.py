"""Keep the memory a frame frees for the next frame (glibc's malloc; elsewhere nothing is done).

A 1280x720 frame makes and frees arrays of 1-8 MB (colour, grey, float copies, gradients). glibc
hands blocks that large straight from and back to the kernel (mmap / munmap) until its threshold,
which it moves itself as blocks are freed, has grown past them, and it gives a heap's free top
back to the kernel past a trim threshold. Which of those happens depends on the order in which
threads allocated and freed so far, so the same code paid ~3 000 page faults a frame (~12 MB
touched afresh, 5-7 ms of kernel CPU) in one run and almost none in another; in a virtual machine
a fresh page can cost the host's work as well. Fixed thresholds make it the same every run: blocks
up to 32 MB come from the heap and freed ones are reused, and a heap's top is given back only past
`TRIM_BYTES`. Process-wide, set once when a Detector is made with `keep_freed_memory` (off by
default: docs/detector.md has the measurements), as OpenCV's thread count is.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging

log = logging.getLogger("cinetransfer.detector")

#: glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: the largest threshold glibc takes on 64-bit (4 MiB x sizeof(long)): a 720p float64 plane is 7 MB
MMAP_BYTES = 32 * 1024 * 1024
#: a heap's free top above this goes back to the kernel (bounds what a finished burst keeps)
TRIM_BYTES = 512 * 1024 * 1024

_done = False


def keep_freed_memory() -> bool:
    """Fix glibc's mmap and trim thresholds (above) for this process; True if they are set. Once per
    process; a C library without `mallopt` (musl, macOS) is left as it is."""
    global _done
    if _done:
        return True
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt if name else None
    except (OSError, AttributeError):
        mallopt = None
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    _done = bool(mallopt(M_MMAP_THRESHOLD, MMAP_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_BYTES))
    if not _done:
        log.debug("mallopt refused the thresholds: the allocator keeps its own")
    return _done
