"""Image files and encoded image bytes -> BGR arrays, with the codec libraries' own
messages kept off the terminal.

libpng, libjpeg and libtiff report a damaged file by writing to the process's stderr
(``libpng error: IDAT: CRC error``, ``Premature end of JPEG file``), and OpenCV logs a
file it cannot open; inside a tracking run these lines would interleave with the
progress bar and say nothing about which frame. Here the C-level stderr (file
descriptor 2) goes to a temporary file while a frame decodes, and what the library
wrote becomes part of the frame's skip reason instead. (POSIX file descriptors: on
Windows a library that writes to its own C runtime's stderr may still show.)
"""
from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

_capture = None   # the temporary file fd 2 is pointed at while decoding (opened once)
#: fd 2 belongs to the whole process: one redirection at a time; a nested or concurrent
#: use waits (another thread) or, in the thread already redirecting, adds nothing
_lock = threading.RLock()
_depth = 0


@contextmanager
def library_messages():
    """Redirect fd 2 to a temporary file for the ``with`` body; yields a list that then
    holds the lines the C libraries wrote (empty when they were silent). Anything else
    the process writes to fd 2 meanwhile lands there too, so the body should be one
    library call. Thread-safe (a lock); nested use in one thread redirects once."""
    global _capture, _depth
    lines: list[str] = []
    with _lock:
        if _depth:
            yield lines
            return
        if _capture is None:
            _capture = tempfile.TemporaryFile()
        if sys.stderr is not None:
            sys.stderr.flush()
        saved = os.dup(2)
        _capture.seek(0)
        _capture.truncate()
        os.dup2(_capture.fileno(), 2)
        _depth += 1
        try:
            yield lines
        finally:
            _depth -= 1
            os.dup2(saved, 2)
            os.close(saved)
            _capture.seek(0)
            text = _capture.read(4096).decode("utf-8", "replace")
            lines.extend(s.strip() for s in text.splitlines() if s.strip())


#: OpenCV's log prefix, e.g. "[ WARN:0@0.104] global grfmt_png.cpp:793 readFromStreamOrBuffer "
_OPENCV_PREFIX = re.compile(r"^\[\s*\w+:[^\]]*\]\s*(?:global\s+)?\S+:\d+\s+\w+\s+")


def _message(lines: list[str]) -> str:
    """The first line a library wrote, without OpenCV's log prefix (at most 200 characters)."""
    return _OPENCV_PREFIX.sub("", lines[0])[:200] if lines else ""


#: libjpeg's warnings for data cut short: it still returns an image, grey below the
#: damage, whose edge would look like a feature, so the frame counts as undecodable
#: (other warnings, e.g. "Corrupt JPEG data: N extraneous bytes before marker", which
#: many MJPEG cameras cause, leave the image intact and are not)
DAMAGED = ("Premature end of JPEG file", "Corrupt JPEG data: premature end of data segment")


def decode_bytes(data) -> tuple[np.ndarray | None, str]:
    """(H x W x 3 uint8 BGR image or None, the codec's first message or "") of an encoded
    image (PNG, JPEG, TIFF, ... whatever cv2.imdecode reads); None also for a JPEG that
    libjpeg reports as cut short or damaged."""
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, (bytes, bytearray, memoryview)) \
        else np.asarray(data, dtype=np.uint8).ravel()
    if buf.size == 0:
        return None, "empty"
    with library_messages() as lines:
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if any(line.startswith(DAMAGED) for line in lines):
        img = None
    return img, _message(lines)


def read_image_file(path: Path) -> tuple[np.ndarray | None, str | None]:
    """(BGR image, None) of an image file, or (None, why it cannot be used): missing
    (also a symbolic link to nothing), unreadable, empty, or not decodable."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None, f"{path.name} is missing" + (" (a link to nothing)" if path.is_symlink() else "")
    except OSError as e:
        return None, f"{path.name} cannot be read ({e.strerror or e})"
    img, message = decode_bytes(data)
    if img is None:
        return None, f"{path.name} does not decode" + (f" ({message})" if message else "")
    return img, None
