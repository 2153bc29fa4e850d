"""A tracking run's overlay video (``--video``): each frame drawn with the pose the run
reports for it.

Frames are drawn as they are tracked, with the streamed answers. An offline
estimator (``batch``) replaces every streamed answer after the last frame
(trajectory.csv is rewritten), so its video is then drawn again, in a second pass
over the recording with the refined poses, into ``REFINED_NAME`` and renamed over the
first: an interrupted run keeps the streamed video, as it keeps the streamed rows. The
detections (without their heatmaps, which the video does not draw) and observations of
the first pass are kept for the second (a few kB per frame); the images are read again.
"""
from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
import time
from pathlib import Path

from tqdm import tqdm

from graphtrack.errors import FrameError
from graphtrack.estimate.base import Estimate
from graphtrack.eval.overlay import OverlayWriter
from graphtrack.io.context import TrackingContext
from graphtrack.io.recording import Recording

#: the refined video while it is drawn (renamed to overlay.mp4 when complete)
REFINED_NAME = "overlay.refined.mp4"


class RunOverlay:
    """overlay.mp4 of one run; ``offline``: drawn again by :meth:`finish` (module doc)."""

    def __init__(self, path: Path, ctx: TrackingContext, rec: Recording, offline: bool):
        self.path, self.ctx, self.rec = Path(path), ctx, rec
        self.writer = self._writer(self.path)
        self.kept: dict[int, tuple] | None = {} if offline else None   # index -> (detection, observation, right)

    def _writer(self, path: Path, title: str | None = None) -> OverlayWriter:
        return OverlayWriter(path, self.ctx, labels=self.rec.labels, labels_right=self.rec.labels_right, title=title)

    def __enter__(self):
        return self

    def __exit__(self, kind, error, tb) -> None:
        """Leaving the run by an exception (Ctrl-C, a full disk): the streamed video is
        closed as far as it got, the frames held back for its frame rate included, as
        trajectory.csv keeps the rows written; :meth:`finish` ends a run that completed."""
        if kind is not None:
            with contextlib.suppress(Exception):   # the exception that ended the run is the one to report
                self.writer.close()

    def write(self, frame, estimate: Estimate, detection, observation, tip, right) -> float:
        """Draw a tracked frame with its streamed answer (offline: keep what a redraw needs);
        returns the milliseconds it took."""
        t = time.perf_counter()
        self.writer.write(frame, estimate, detection, observation, tip, right)
        if self.kept is not None:
            det_r, obs_r = right
            self.kept[int(frame.index)] = (_slim(detection), observation, (_slim(det_r), obs_r))
        return 1e3 * (time.perf_counter() - t)

    def finish(self, rows: list, tips: list, right: bool, progress: bool = False) -> None:
        """Close the streamed video; offline, draw every tracked frame again with its refined
        pose (``rows``: the run's (index, stamp, q, ms, E), ``tips`` their tip pixels),
        reading the images again (``right``: the right ones too; ``progress``: a bar), and
        replace it."""
        self.writer.close()
        if self.kept is None or not rows:
            return
        refined = {int(r[0]): (r[4], tip) for r, tip in zip(rows, tips)}
        last = max(refined)
        tmp = self.path.with_name(REFINED_NAME)
        with self._writer(tmp, "refined") as writer, tqdm(total=len(refined), desc="overlay, refined", unit="frame",
                                               file=sys.stderr, disable=not progress) as bar:
            for frame in self.rec.frames(right=right):
                if isinstance(frame, FrameError) or int(frame.index) not in refined:
                    continue
                E, tip = refined[int(frame.index)]
                det, obs, right_views = self.kept[int(frame.index)]
                writer.write(frame, Estimate(E), det, obs, tip, right_views)
                bar.update(1)
                if int(frame.index) >= last:
                    break
        os.replace(tmp, self.path)


def _slim(detection):
    """The detection without its heatmap (None stays None)."""
    return None if detection is None else dataclasses.replace(detection, heatmap=None)
