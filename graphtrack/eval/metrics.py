"""Tip-error metrics against labels.csv (and, when present, truth.csv).

The method's headline number is the 2-D tool-tip error: the distance (px)
between the estimated tip, projected into the RAW (distorted) left image, and
the hand-labelled tip, also reported in % of the image diagonal.
"""
from __future__ import annotations

import numpy as np


def summary(values: np.ndarray) -> dict:
    """mean, std, median, p95 of finite values (NaN when there are none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return {"mean": float("nan"), "std": float("nan"), "median": float("nan"), "p95": float("nan")}
    return {"mean": float(v.mean()), "std": float(v.std()), "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95))}


def tip_errors(frames: np.ndarray, tips: np.ndarray, labels: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per labelled frame the 2-D tip error (px).

    frames: (F,) frame indices of the trajectory; tips: (F, 2) estimated raw
    tip pixels; labels: frame -> (u, v). Returns (scored frame indices, errors).
    A labelled frame absent from the trajectory (skipped) is not scored.
    """
    index = {int(f): i for i, f in enumerate(frames)}
    scored, errs = [], []
    for f in sorted(labels):
        i = index.get(int(f))
        if i is None or not np.all(np.isfinite(tips[i])):
            continue
        scored.append(int(f))
        errs.append(float(np.linalg.norm(np.asarray(tips[i]) - np.asarray(labels[f]))))
    return np.asarray(scored, dtype=int), np.asarray(errs, dtype=float)


def tip_metrics(frames, tips, labels, diagonal: float, skipped: dict[str, int] | None = None,
                n_frames: int | None = None) -> dict:
    """The metrics.json document: tip error in px and in % of the image diagonal."""
    scored, errs = tip_errors(np.asarray(frames), np.asarray(tips), labels)
    doc = {
        "tip_error_px": summary(errs),
        "tip_error_percent_diagonal": summary(100.0 * errs / diagonal),
        "frames_scored": int(len(scored)),
        "frames_labelled": int(len(labels)),
        "frames_skipped": int(sum((skipped or {}).values())),
        "skipped_reasons": dict(skipped or {}),
        "image_diagonal_px": float(diagonal),
    }
    if n_frames is not None:
        doc["frames_total"] = int(n_frames)
    return doc
