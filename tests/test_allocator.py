"""graphtrack.allocator: freed frame-sized buffers are reused without page faults."""
import platform
import resource

import numpy as np
import pytest

from graphtrack.allocator import keep_freed_memory

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


def _faults_of_frames(n: int) -> int:
    """Minor page faults over n 'frames' that each allocate, touch and free 1 MiB and 3 MiB."""
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(n):
        a = np.empty(1 << 20, np.uint8)
        a[::4096] = 1
        b = np.empty(3 << 20, np.uint8)
        b[::4096] = 1
        del a, b
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0


@pytest.mark.skipif(not GLIBC, reason="mallopt thresholds are glibc's")
def test_freed_buffers_are_reused_without_page_faults():
    assert keep_freed_memory() is True
    assert keep_freed_memory() is True            # idempotent
    _faults_of_frames(2)                          # the heap grows once
    # a fresh mmap per buffer would fault in 1024 pages per frame
    assert _faults_of_frames(50) < 50


@pytest.mark.skipif(GLIBC, reason="only where the C library is not glibc")
def test_other_c_libraries_are_left_alone():
    assert keep_freed_memory() is False
