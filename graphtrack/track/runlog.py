"""What one tracking run collects as it reads a recording: per tracked frame its
row, tip pixel and per-stage milliseconds; the frames skipped and why; the summary
(timings, frames/s) that metrics.json reports.
"""
from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from graphtrack.errors import FrameError
from graphtrack.io.frame import Frame
from graphtrack.io.recording import Recording

#: per-frame stages timed (``video``: drawing the overlay, not counted in the per-frame cost)
STAGES = ("decode", "undistort", "detect", "observe", "estimate", "write", "video")


def warn(message: str, quiet: bool) -> None:
    """One line on stderr (none when ``quiet``), written past an open progress bar
    (``tqdm.write``: a log file or pipe gets the line on its own, not glued to the bar's)."""
    if not quiet:
        tqdm.write(f"graphtrack: {message}", file=sys.stderr)


class SkipCounter(Counter):
    """Skipped frames per reason, and the first message of each (metrics.json ``skip_examples``)."""

    def __init__(self):
        super().__init__()
        self.examples: dict[str, str] = {}

    #: skips of one reason warned about one by one; the rest are counted, not listed
    WARN_EACH = 10
    #: reasons whose first warning names every frame skipped for it (the rest are counted only)
    WARN_ONCE = frozenset({"video_ended"})

    def skip(self, error: FrameError, quiet: bool) -> None:
        """Count a skipped frame, keep its reason's first message, warn unless quiet (each
        of the first WARN_EACH of a reason, then once that the rest are only counted; a
        WARN_ONCE reason: its first only)."""
        self[error.reason] += 1
        self.examples.setdefault(error.reason, str(error))
        if error.reason in self.WARN_ONCE:
            if self[error.reason] == 1:
                warn(f"warning: skipping {error}", quiet)
        elif self[error.reason] <= self.WARN_EACH:
            warn(f"warning: skipping {error}", quiet)
        elif self[error.reason] == self.WARN_EACH + 1:
            warn(f"warning: skipping frame {error.frame} and further '{error.reason}' frames: counted in "
                 "metrics.json (skipped_reasons), not listed", quiet)


@dataclass
class RunLog:
    """What one tracking run has collected so far: per tracked frame its index, tip
    pixel and (index, stamp, q, total ms, E) row; per-stage and per-frame milliseconds;
    the skip reasons; frames read (tracked or skipped)."""

    frames: list = field(default_factory=list)
    tips: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    stage_ms: dict = field(default_factory=lambda: {s: [] for s in STAGES})
    frame_ms: list = field(default_factory=list)
    skipped: SkipCounter = field(default_factory=SkipCounter)
    read: int = 0
    informative: list = field(default_factory=list)   # per tracked frame: a shaft or marker detected

    def add(self, frame: Frame, E: np.ndarray, tip: np.ndarray, ms: dict, total_ms: float,
            frame_ms: float) -> None:
        for s in STAGES:
            self.stage_ms[s].append(ms.get(s, 0.0))
        self.frame_ms.append(frame_ms)
        self.frames.append(frame.index)
        self.tips.append(tip)
        self.rows.append((frame.index, frame.stamp, frame.q, total_ms, E))

    def summary(self, wall: float) -> dict:
        """Frame counts, median ms per stage, fps over the wall time and the steady state:
        every per-frame cost (decode ... write; not the overlay video's drawing, so that runs
        with and without ``--video`` compare) of frames 1.. (frame 0 also pays the
        start-up: the bag's joint pass, first use of the detector), no finish(); NaN (null in
        metrics.json) without a frame 1."""
        out = {"timing_ms_median": {s: float(np.median(v)) if v else 0.0 for s, v in self.stage_ms.items()},
               "fps": float(len(self.frames) / wall) if wall > 0 else float("nan")}
        steady = self.frame_ms[1:]   # none in a one-frame run: null, not the start-up's cost
        out["frame_ms_mean"] = float(np.mean(steady)) if steady else float("nan")
        out["fps_steady"] = float(1e3 / np.mean(steady)) if steady else float("nan")
        out["wall_s"] = float(wall)
        return out


def read_frames(rec: Recording, max_frames: int | None, run: RunLog, bar, right: bool = True):
    """(item, decode ms, start time) for up to ``max_frames`` recording items, counted in run.read;
    ``right`` False: the right images are not read."""
    it = iter(rec.frames(right=right))
    while max_frames is None or run.read < max_frames:
        t0 = time.perf_counter()
        try:
            item = next(it)
        except StopIteration:
            return
        run.read += 1
        if bar is not None:
            bar.update(1)
        yield item, 1e3 * (time.perf_counter() - t0), t0

