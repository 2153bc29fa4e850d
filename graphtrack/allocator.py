"""The tracking process's memory allocator: freed frame buffers are kept for the next frame.

Every frame allocates and frees the same large buffers: the learned net's activations
(0.1-1 MB each at 135x240), image copies, the pixel sets' arrays. glibc's malloc serves a
block above its mmap threshold (128 kB at start, raised only as mmapped blocks are freed)
with a fresh ``mmap`` and hands a heap top above its trim threshold back to the kernel,
so the next frame page-faults the same memory in again. :func:`keep_freed_memory` fixes
the two thresholds at the ceiling glibc's own adjustment moves towards on 64-bit systems
(mmap 32 MiB, trim twice that): blocks up to 32 MiB come from the heap and freed ones
stay there for reuse. A 1080x1920 frame (6 MiB) is below it; peak memory is measured in
benchmarks/RESULTS.md ("peak RSS").

Measurements: docs/decisions/stereo-detection.md ("Freed buffers kept").

Elsewhere (macOS, Windows, musl) nothing is changed.
"""
from __future__ import annotations

import ctypes
import functools
import platform

#: blocks up to this size come from the heap (glibc's DEFAULT_MMAP_THRESHOLD_MAX on 64-bit)
MMAP_THRESHOLD = 32 << 20
#: the heap keeps up to this much freed memory at its top (glibc's rule: twice the above)
TRIM_THRESHOLD = 2 * MMAP_THRESHOLD

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3    # mallopt parameters, <malloc.h>


@functools.cache
def keep_freed_memory() -> bool:
    """Fix glibc malloc's mmap and trim thresholds (module doc) for this process, once; True
    when they are set, False where the C library is not glibc (then every later call returns
    False at once: ``platform.libc_ver`` reads the interpreter's binary)."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
