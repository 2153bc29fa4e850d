"""Videos written at the recording's own frame rate.

:class:`StampedVideoWriter` takes (image, stamp) pairs and writes an mp4
(OpenCV's mp4v codec) whose frame rate is the recording's: 1 / the median
interval between the stamps of the first ``probe`` frames (held back until
then), or ``fallback_fps`` when the stamps do not tell (fewer than two
finite, increasing stamps). ``close()`` reads the finished file's frame count back,
so a video cut short (full disk) is an InputError, not a silent broken file.
"""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from graphtrack.errors import InputError
from graphtrack.io.stamps import median_interval

FALLBACK_FPS = 30.0


def open_video(path: str | Path) -> cv2.VideoCapture:
    """``cv2.VideoCapture(path)`` with FFmpeg's own log lines off (a damaged file would
    print "moov atom not found" and the like before graphtrack's one-line message);
    OPENCV_FFMPEG_LOGLEVEL set by the user wins. Read at OpenCV's first capture."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")   # AV_LOG_QUIET
    return cv2.VideoCapture(str(path))


#: the first bytes of the still images FFmpeg would open as a one-frame "video"
STILL_IMAGES = {b"\x89PNG\r\n\x1a\n": "PNG", b"\xff\xd8\xff": "JPEG"}


def still_image(path: str | Path, cap: cv2.VideoCapture) -> str | None:
    """"PNG" or "JPEG" when the file at ``path``, opened as ``cap``, is one still image (its
    first bytes are the format's signature and no second frame follows; a stream of many
    JPEGs is a video), else None. Reads from ``cap``."""
    with open(path, "rb") as f:
        head = f.read(8)
    kind = next((k for sig, k in STILL_IMAGES.items() if head.startswith(sig)), None)
    return kind if kind is not None and not (cap.grab() and cap.grab()) else None


def frame_rate(stamps, fallback: float = FALLBACK_FPS) -> float:
    """1 / median positive interval of ``stamps`` (s), within [1, 240] frames/s; else ``fallback``."""
    dt = median_interval(stamps)
    return float(np.clip(1.0 / dt, 1.0, 240.0)) if dt > 0 else float(fallback)


class StampedVideoWriter:
    """``write(image, stamp)`` BGR frames of one size; ``close()`` (or a with block) finishes the file."""

    def __init__(self, path: str | Path, fps: float | None = None, probe: int = 10,
                 fallback_fps: float = FALLBACK_FPS):
        self.path = Path(path)
        self.fps = None if fps is None else float(fps)
        self.probe = int(probe)
        self.fallback_fps = float(fallback_fps)
        self.frames_written = 0
        self._held: list[tuple[np.ndarray, float]] = []
        self._writer = None
        self._size = None

    def write(self, image: np.ndarray, stamp: float = float("nan")) -> None:
        if self._writer is None and self.fps is None:
            self._held.append((image, float(stamp)))
            if len(self._held) >= self.probe:
                self._flush()
            return
        self._emit(image)

    def _flush(self) -> None:
        if self.fps is None:
            self.fps = frame_rate([s for _, s in self._held], self.fallback_fps)
        held, self._held = self._held, []
        for image, _ in held:
            self._emit(image)

    def _emit(self, image: np.ndarray) -> None:
        if self._writer is None:
            self._size = (int(image.shape[1]), int(image.shape[0]))
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"),
                                           self.fps or self.fallback_fps, self._size)
            if not self._writer.isOpened():
                raise InputError(f"{self.path}: cannot open an mp4 video writer")
        if (image.shape[1], image.shape[0]) != self._size:
            image = cv2.resize(image, self._size)
        self._writer.write(np.ascontiguousarray(image))
        self.frames_written += 1

    @property
    def frames_received(self) -> int:
        """Frames given to write(), including those held back until the frame rate is known."""
        return self.frames_written + len(self._held)

    def close(self) -> None:
        """Finish the file; InputError naming it when it does not hold every frame written
        (OpenCV's writer fails silently, e.g. on a full disk)."""
        if self._held:
            self._flush()
        if self._writer is not None:
            self._writer.release()
            self._writer = None
            cap = open_video(self.path)
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
            cap.release()
            if n != self.frames_written:
                raise InputError(f"{self.path}: cannot write the video ({n} of {self.frames_written} frames "
                                 "readable; is the disk full?)")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
