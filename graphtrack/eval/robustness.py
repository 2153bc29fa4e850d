"""Robustness figures of one tracked recording from its per-frame tip errors (px).

The recording is cut by its *disturbances* (a full occlusion of the shaft, the
tool out of view: frame intervals ``[start, end)`` from the simulator's
scenario.json) into *visible segments*. Over a segment a tracker has
*converged* from frame k on when its tip error stays below ``threshold`` px
from k to the segment's end:

- frames to converge: k - 0 for the first segment (start-up);
- frames to re-acquire: k - end of the disturbance, for each later segment;
- worst window: the largest mean error of any ``window`` consecutive frames
  minus the kinematics baseline's mean over the same frames (> 0: worse than
  no tracking there).

A segment the tracker never converges on gives ``inf``; a segment shorter
than nothing to judge (empty) gives ``nan``. NaN errors (tip not projectable)
count as not converged.
"""
from __future__ import annotations

import numpy as np

CONVERGED_PX = 5.0
WINDOW = 10


def segments(n: int, disturbances: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """The visible segments [start, end) of an n-frame recording between the disturbances."""
    cuts = sorted((max(0, int(a)), min(n, int(b))) for a, b in disturbances if int(b) > int(a))
    out, t = [], 0
    for a, b in cuts:
        if a > t:
            out.append((t, a))
        t = max(t, b)
    if t < n:
        out.append((t, n))
    return out


def frames_to_converge(err: np.ndarray, start: int = 0, end: int | None = None,
                       threshold: float = CONVERGED_PX) -> float:
    """Frames from ``start`` until the error stays below ``threshold`` up to ``end`` (inf: never)."""
    e = np.asarray(err, float)[start:end]
    if e.size == 0:
        return float("nan")
    bad = np.flatnonzero(~(e < threshold))
    return 0.0 if bad.size == 0 else (float(bad[-1] + 1) if bad[-1] + 1 < e.size else float("inf"))


def reacquisition_frames(err: np.ndarray, disturbances: list[tuple[int, int]],
                         threshold: float = CONVERGED_PX) -> list[float]:
    """Frames to re-converge after each disturbance, one value per visible segment after one."""
    segs = segments(len(err), disturbances)
    return [frames_to_converge(err, a, b, threshold) for a, b in segs if a > 0]


def startup_frames(err: np.ndarray, disturbances: list[tuple[int, int]],
                   threshold: float = CONVERGED_PX) -> float:
    """Frames to converge in the first visible segment (nan when it does not start at frame 0)."""
    segs = segments(len(err), disturbances)
    if not segs or segs[0][0] != 0:
        return float("nan")
    return frames_to_converge(err, *segs[0], threshold)


def worst_window_excess(err: np.ndarray, baseline: np.ndarray, window: int = WINDOW) -> float:
    """max over ``window``-frame windows of mean(err) - mean(baseline) (px); NaN frames are left out
    of both means; nan when no window has a finite pair."""
    e, b = np.asarray(err, float), np.asarray(baseline, float)
    ok = np.isfinite(e) & np.isfinite(b)
    d = np.where(ok, e - b, 0.0)
    if len(d) < window or not ok.any():
        return float("nan")
    k = np.ones(window)
    num, cnt = np.convolve(d, k, "valid"), np.convolve(ok.astype(float), k, "valid")
    valid = cnt > 0
    return float(np.max(num[valid] / cnt[valid])) if valid.any() else float("nan")


def recording_figures(err: np.ndarray, baseline: np.ndarray, disturbances: list[tuple[int, int]],
                      threshold: float = CONVERGED_PX, window: int = WINDOW) -> dict:
    """The per-recording figures: mean error, start-up, re-acquisitions (with the length of
    the segment each was judged on), worst window excess."""
    e = np.asarray(err, float)
    segs = segments(len(e), disturbances)
    return {"mean_px": float(np.nanmean(e)) if np.isfinite(e).any() else float("nan"),
            "startup_frames": startup_frames(e, disturbances, threshold),
            "startup_segment": segs[0][1] if segs and segs[0][0] == 0 else 0,
            "reacquire_frames": reacquisition_frames(e, disturbances, threshold),
            "reacquire_segments": [b - a for a, b in segs if a > 0],
            "worst_window_excess_px": worst_window_excess(e, baseline, window)}


#: the shortest stretch of frames without detections that the tracker reports (frames)
NO_DETECTION_FRAMES = 15


def no_detection_stretches(frames: list[int], informative: list[bool],
                           min_frames: int = NO_DETECTION_FRAMES) -> list[list[int]]:
    """[start, end) frame-index intervals of at least ``min_frames`` consecutive tracked
    frames whose observation had no shaft and no marker (the estimate there is the
    motion model's prediction). ``frames``: tracked frame indices in order; ``informative``:
    per tracked frame, whether its observation had a detection."""
    out, start, count = [], None, 0
    for i, (f, ok) in enumerate(zip(frames, informative)):
        if not ok:
            if start is None:
                start, count = f, 0
            count += 1
        if ok or i == len(frames) - 1:
            if start is not None and count >= min_frames:
                out.append([int(start), int(f if ok else f + 1)])
            if ok:
                start = None
    return out
