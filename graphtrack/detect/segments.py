"""Line segments from a line heatmap L and a junction heatmap J (the learned detector's outputs).

At the heatmaps' own (reduced) scale: probabilistic Hough
(cv2.HoughLinesP) on {L >= line_threshold} proposes candidates; each is
refined by a heatmap-weighted total-least-squares line fit to the
above-threshold pixels within ``fit_band`` px of it, grown along the fitted
line over all such pixels (split at gaps > ``max_gap``: the run holding the
candidate's centre) and refitted; its extent is that of its supporting
pixels, and each endpoint snaps to a junction peak (3x3 local maximum of
J >= junction_threshold) within ``snap`` px of it along the line;
near-duplicates (angle < 0.05 rad, offset < 2 px, overlapping) keep the
best supported one.

Candidates that lie on a line already fitted (within 0.05 rad, both ends within
``fit_band``, inside its run) are not fitted again: HoughLinesP proposes several per
heatmap ridge, and each would grow to the same run (docs/decisions/stereo-detection.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class ExtractConfig:
    """Segment extraction at the reduced scale (px of the reduced image)."""

    line_threshold: float = 0.5       #: L >= this is a line pixel
    junction_threshold: float = 0.3   #: J peaks above this are junctions
    hough_votes: int = 12             #: cv2.HoughLinesP threshold
    min_length: float = 8.0           #: px (reduced), shorter segments dropped
    max_gap: float = 4.0              #: px (reduced), HoughLinesP maxLineGap
    fit_band: float = 1.5             #: px (reduced), pixels used by the line fit
    min_support: int = 8              #: supporting pixels needed
    snap: float = 3.0                 #: px (reduced), endpoint-to-junction snap radius
    max_segments: int = 32


def _tls(Q: np.ndarray, wq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted total-least-squares line: (centroid, unit direction).

    The direction is the principal eigenvector of the weighted scatter
    [[sxx, sxy], [sxy, syy]], in closed form at the angle 0.5 atan2(2 sxy, sxx - syy)
    (a 2x2 eigh costs ~20 us in numpy's call overhead, and this runs per candidate)."""
    sw = wq.sum()
    c = np.array([wq @ Q[:, 0], wq @ Q[:, 1]]) / sw
    dx, dy = Q[:, 0] - c[0], Q[:, 1] - c[1]
    wx = wq * dx
    phi = 0.5 * np.arctan2(2.0 * (wx @ dy), wx @ dx - (wq * dy) @ dy)
    return c, np.array([np.cos(phi), np.sin(phi)])


def _junction_peaks(J: np.ndarray, thr: float) -> np.ndarray:
    """(n, 2) (x, y) of 3x3 local maxima of J >= thr (reduced px)."""
    dil = cv2.dilate(J, np.ones((3, 3), np.uint8))
    ys, xs = np.nonzero((J >= thr) & (J >= dil))
    return np.stack([xs, ys], 1).astype(float)


def _grow_and_fit(P: np.ndarray, w: np.ndarray, a: np.ndarray, b: np.ndarray, cfg: ExtractConfig):
    """One Hough candidate a -> b refined (module doc, step 2): (centroid c, unit
    direction u, supporting pixels' indices into P) of the refitted line, or None."""
    d = b - a
    n = np.hypot(*d)
    if n < 1e-9:
        return None
    d /= n
    nrm = np.array([-d[1], d[0]])
    Pa = P - a
    r = Pa @ nrm
    t = Pa @ d
    sel = (np.abs(r) <= cfg.fit_band) & (t >= -cfg.max_gap) & (t <= n + cfg.max_gap)
    if np.count_nonzero(sel) < cfg.min_support:
        return None
    c, u = _tls(P[sel], w[sel])
    # grow along the fitted line: all pixels in the band, split at gaps,
    # keep the run holding the candidate's centre (else the longest), refit
    X = P - c
    band = np.abs(X @ np.array([-u[1], u[0]])) <= cfg.fit_band
    tq = X[band] @ u
    order = np.argsort(tq)
    ts = tq[order]
    gaps = np.flatnonzero(ts[1:] - ts[:-1] > cfg.max_gap)
    starts = np.concatenate(([0], gaps + 1))
    ends = np.concatenate((gaps, [len(ts) - 1]))
    tc = (0.5 * (a + b) - c) @ u
    hold = np.flatnonzero((ts[starts] <= tc) & (ts[ends] >= tc))
    k = int(hold[0]) if len(hold) else int(np.argmax(ts[ends] - ts[starts]))
    cnt = ends[k] - starts[k] + 1
    if ts[ends[k]] - ts[starts[k]] < cfg.min_length or cnt < cfg.min_support:
        return None
    run = np.flatnonzero(band)[order[starts[k]:ends[k] + 1]]
    c, u = _tls(P[run], w[run])
    return c, u, run


def _snap(e: np.ndarray, c: np.ndarray, u: np.ndarray, peaks: np.ndarray, cfg: ExtractConfig) -> np.ndarray:
    """Endpoint e on the line (c, u) moved to the projection of the nearest junction
    peak within ``snap`` px (and ``fit_band`` + 0.5 px of the line); else e."""
    dp = peaks - e
    along = dp @ u
    perp = np.abs(dp @ np.array([-u[1], u[0]]))
    ok = (np.hypot(along, perp) <= cfg.snap) & (perp <= cfg.fit_band + 0.5)
    if not ok.any():
        return e
    j = np.flatnonzero(ok)[np.argmin(np.hypot(along, perp)[ok])]
    return c + ((peaks[j] - c) @ u) * u  # project onto the fitted line


def _duplicate(S: np.ndarray, i: int, keep: list[int]) -> bool:
    """Segment i near-duplicates a kept one: angle < 0.05 rad, midpoint < 2 px from
    its line, overlapping by more than 0.3 of the shorter."""
    a, b = S[i, :2], S[i, 2:]
    mid = 0.5 * (a + b)
    di = (b - a) / max(np.hypot(*(b - a)), 1e-9)
    for j in keep:
        aj, bj = S[j, :2], S[j, 2:]
        dj = (bj - aj) / max(np.hypot(*(bj - aj)), 1e-9)
        if abs(di @ dj) < np.cos(0.05):
            continue
        nj = np.array([-dj[1], dj[0]])
        if abs((mid - aj) @ nj) > 2.0:
            continue
        ta, tb = sorted(((a - aj) @ dj, (b - aj) @ dj))
        lj = np.hypot(*(bj - aj))
        if min(tb, lj) - max(ta, 0.0) > 0.3 * min(tb - ta, lj):
            return True
    return False


def _explained(a: np.ndarray, b: np.ndarray, fitted: list, cfg: ExtractConfig) -> bool:
    """Candidate a -> b lies on a line already fitted (c, u, t_min, t_max): within 0.05
    rad of it, both ends within ``fit_band`` of it and inside its run (+ ``max_gap``).
    Its own fit would grow to the same run and be dropped as that line's duplicate, so
    it is not fitted (HoughLinesP proposes several candidates per heatmap ridge)."""
    d = b - a
    n = np.hypot(*d)
    if n < 1e-9:
        return False
    for c, u, t0, t1 in fitted:
        if abs(d @ u) < np.cos(0.05) * n:
            continue
        nrm = np.array([-u[1], u[0]])
        if abs((a - c) @ nrm) > cfg.fit_band or abs((b - c) @ nrm) > cfg.fit_band:
            continue
        ta, tb = (a - c) @ u, (b - c) @ u
        if min(ta, tb) >= t0 - cfg.max_gap and max(ta, tb) <= t1 + cfg.max_gap:
            return True
    return False


def extract_segments(L: np.ndarray, J: np.ndarray | None = None,
                     config: ExtractConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Segments (S, 4) (x1, y1, x2, y2) and their support (S,) from a line
    heatmap L (h, w) in [0, 1] and an optional junction heatmap J, in the
    heatmaps' own pixels (see the module doc, step 2)."""
    cfg = config or ExtractConfig()
    L = np.asarray(L, np.float32)
    empty = np.zeros((0, 4)), np.zeros(0)
    if L.ndim != 2 or min(L.shape) < 2:
        return empty
    mask = (L >= cfg.line_threshold).astype(np.uint8)
    ys, xs = np.nonzero(mask)
    if len(xs) < cfg.min_support:
        return empty
    hl = cv2.HoughLinesP(mask, 1, np.pi / 180, cfg.hough_votes, minLineLength=cfg.min_length,
                         maxLineGap=cfg.max_gap)
    if hl is None:
        return empty
    cand = hl.reshape(-1, 4).astype(float)
    cand = cand[np.argsort(-np.hypot(cand[:, 2] - cand[:, 0], cand[:, 3] - cand[:, 1]), kind="stable")]
    cand = cand[: 4 * cfg.max_segments]
    P = np.stack([xs, ys], 1).astype(float)
    w = L[ys, xs].astype(float)
    peaks = _junction_peaks(np.asarray(J, np.float32), cfg.junction_threshold) if J is not None \
        else np.zeros((0, 2))
    out, support, fitted = [], [], []
    for x1, y1, x2, y2 in cand:
        a, b = np.array([x1, y1]), np.array([x2, y2])
        if _explained(a, b, fitted, cfg):
            continue
        fit = _grow_and_fit(P, w, a, b, cfg)
        if fit is None:
            continue
        c, u, run = fit
        tq = (P[run] - c) @ u
        fitted.append((c, u, float(tq.min()), float(tq.max())))
        e0, e1 = c + float(tq.min()) * u, c + float(tq.max()) * u
        if len(peaks):
            e0, e1 = _snap(e0, c, u, peaks, cfg), _snap(e1, c, u, peaks, cfg)
        out.append(np.concatenate((e0, e1)))
        support.append(float(w[run].sum()))
    if not out:
        return empty
    S = np.array(out)
    sup = np.array(support)
    order = np.argsort(-sup, kind="stable")
    S, sup = S[order], sup[order]
    keep: list[int] = []
    for i in range(len(S)):
        if not _duplicate(S, i, keep):
            keep.append(i)
        if len(keep) >= cfg.max_segments:
            break
    return S[keep], sup[keep]
