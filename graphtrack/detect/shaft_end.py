"""The shaft's distal end: where the dark shaft meets the wrist, along its image.

The two silhouette lines fix the shaft's image across its axis but say nothing
about where along the axis it is (the *slide*), which is what a hand-eye error
leaves loosest at start-up (docs/decisions/shaft-end.md). The shaft of a dVRK
instrument is dark and ends in a metal wrist, so its image has a sharp
dark-to-bright step along the middle of the shaft's band. This module finds it.

Given the two detected shaft lines l_1, l_2 (undistorted full-size px) and the
distal direction (from the prediction: the side of the band the wrist is on):

1. the axis of the band is the mid-line of l_1 and l_2: for a coordinate s along
   the unit distal direction d (from the detected edges' centroid), the
   cross-section p = o + s d + t n (n normal to d) meets l_i at t_i(s), the band's
   centre is t_c = (t_1 + t_2) / 2 and its half-width h(s) = |t_1 - t_2| / 2;
2. the grey profile g(s) is the median of ``samples`` samples across the middle
   ``width`` of the band (|t - t_c| <= width h), every ``step`` px of s from
   ``search`` px before to ``search`` px after the detected edges' distal end and
   the predicted end (the median ignores a marker or a highlight covering part of
   the cross-section);
3. the step score D(s) = median g over (s, s + L] - median g over [s - L, s),
   L = ``window`` h; the end s* is its first local maximum from the shaft's side
   that reaches max(``min_contrast`` grey levels, ``rival`` x its largest value,
   ``min_ratio`` x the shaft's median): a dark shaft before it, a brighter wrist
   after. The first, not the largest:
   beyond a short wrist seen end-on lies the background, often a larger step.
   A step is kept only if what follows it differs in colour from what lies beside
   the band there, on each side (rows t_c +- ``outside`` h), by at least ``apart``
   x its contrast, and is grey (saturation at most ``max_saturation``): the
   wrist is a narrow band of bare metal, while the background beyond the whole
   tool, or a tissue flap or instrument across the shaft, lies beside it too or
   is coloured;
4. to sub-pixel: on three rows near the mid-line (``centre_rows``, |t - t_c| <= 0.1 h)
   where each crosses the level halfway between the two medians, linearly
   interpolated, nearest s*; the median of the three. Only near the mid-line: the
   end rim's image is an arc of an ellipse that curves back towards the shaft off
   it (by b (1 - sqrt(1 - tau^2)) at t = t_c + tau h, b up to r f / Z), so the
   crossing of the median profile of the middle half lies 0.5-1.3 px short of the
   front point on the simulated recordings; on these rows, at most 0.005 b.

The image is sampled through ``sample(points) -> grey``, so that the caller can
read the raw frame through the distortion (``raw_sampler``) or an undistorted one.
Returns the end point (on the band's mid-line) and d, or None. What it cannot
tell: a flap or an instrument that crosses the shaft no wider than the shaft
looks like a wrist; the estimators' gates and robust losses carry that risk.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class ShaftEndConfig:
    """Settings (px of the full-size undistorted image, grey levels, fractions)."""

    search: float = 40.0       #: px either side of the detected edges' distal end (and the predicted end)
    reach: float = 160.0       #: px: the predicted end widens the profile by at most this
    step: float = 0.5          #: px between profile samples along the axis
    width: float = 0.5         #: fraction of the half-width sampled either side of the axis
    samples: int = 7           #: samples across
    window: float = 0.6        #: L, in half-widths: the two medians' extent
    min_contrast: float = 12.0  #: grey levels between the wrist's and the shaft's medians
    rival: float = 0.25        #: a step this strong (vs the strongest) nearer the shaft comes first
    min_ratio: float = 0.25    #: and at least this x the shaft's grey (a relative step)
    outside: float = 1.6       #: half-widths from the mid-line: 'beside the band'
    apart: float = 0.5         #: the wrist's colour differs from beside the band by this x the step
    max_saturation: float = 0.25  #: the wrist is grey metal: (max - min) / max of its BGR at most this
    min_half_width: float = 3.0  #: px: a narrower band is too thin to sample
    centre_rows: tuple = (-0.1, 0.0, 0.1)  #: the sub-pixel rows, in half-widths from the mid-line


@dataclass
class ShaftEnd:
    """point (2,): the end on the band's mid-line; direction (2,): unit, distal;
    contrast: D(s*) in grey levels."""

    point: np.ndarray
    direction: np.ndarray
    contrast: float


def raw_sampler(image: np.ndarray, camera=None):
    """sample(points (n, 2) undistorted px) -> (n,) grey levels (bilinear; NaN outside
    the image), reading ``image`` (BGR or grey) at the raw pixels of ``camera`` (None or
    no distortion: the image is already undistorted). Only the sampled pixels are
    converted to grey (cv2's BGR weights). ``sample.colour(points)`` -> (n, channels)
    the same samples in the image's own channels."""
    distorted = camera is not None and np.any(np.asarray(camera.dist, float) != 0.0)
    h, w = image.shape[:2]

    def colour(points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, float).reshape(-1, 2)
        if distorted:
            p = camera.distort_pixels(p)
        m = p.astype(np.float32).reshape(1, -1, 2)
        out = cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out = out.reshape(len(p), -1).astype(float)
        inside = (p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)
        return np.where(inside[:, None], out, np.nan)

    def sample(points: np.ndarray) -> np.ndarray:
        c = colour(points)
        return c[:, 0] if c.shape[1] == 1 else c[:, :3] @ _BGR_TO_GREY
    sample.colour = colour
    return sample


_BGR_TO_GREY = np.array([0.114, 0.587, 0.299])


def _normals(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    th = lines[:, 1]
    return np.stack([np.cos(th), np.sin(th)], -1), lines[:, 0]


def _band(lines: np.ndarray, o: np.ndarray, d: np.ndarray, s: np.ndarray):
    """Centre offsets t_c(s) and half-widths h(s) of the band at coordinates s (step 1)."""
    nrm, rho = _normals(lines)
    n = np.array([-d[1], d[0]])
    den = nrm @ n                                  # (2,)
    if np.any(np.abs(den) < 1e-6):
        return None, None
    base = o[None, :] + s[:, None] * d[None, :]    # (S, 2)
    t = (rho[None, :] - base @ nrm.T) / den[None, :]
    return t.mean(1), 0.5 * np.abs(t[:, 0] - t[:, 1])


def _band_points(o, d, s, tc, h, taus) -> np.ndarray:
    """(len(s), len(taus), 2) px: the points o + s d + (t_c(s) + tau h(s)) n of the band,
    for each coordinate s along it and each tau (half-widths from its mid-line)."""
    n = np.array([-d[1], d[0]])
    offs = np.asarray(tc)[:, None] + np.asarray(taus, float)[None, :] * np.asarray(h)[:, None]
    return o + np.asarray(s)[:, None, None] * d + offs[..., None] * n


def _medians(g: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Median of g over the k samples before and after each index (NaN near the ends)."""
    n = len(g)
    before = np.full(n, np.nan)
    after = np.full(n, np.nan)
    if n <= 2 * k:
        return before, after
    win = np.lib.stride_tricks.sliding_window_view(g, k)   # win[i] = g[i:i+k]
    med = np.median(win, axis=1)
    before[k:] = med[:n - k]
    after[:n - k] = med[1:n - k + 1]
    return before, after


def _crossing(g: np.ndarray, i: int, level: float, k: int) -> float | None:
    """The sub-sample index nearest i where g crosses ``level`` upwards, within k samples
    (None if it does not)."""
    best, best_d = None, np.inf
    lo, hi = max(0, i - k), min(len(g) - 1, i + k)
    for j in range(lo, hi):
        a, b = g[j], g[j + 1]
        if a <= level < b:
            x = j + (level - a) / (b - a)
            if abs(x - i) < best_d:
                best, best_d = x, abs(x - i)
    return best


def _steps(D: np.ndarray, min_contrast: float, rival: float) -> np.ndarray:
    """The local maxima of D reaching max(min_contrast, rival max D), from the shaft's side."""
    Dz = np.where(np.isfinite(D), D, -np.inf)
    top = float(Dz.max())
    if not top >= min_contrast:
        return np.zeros(0, int)
    peak = (Dz[1:-1] >= Dz[:-2]) & (Dz[1:-1] > Dz[2:]) & (Dz[1:-1] >= max(min_contrast, rival * top))
    return np.flatnonzero(peak) + 1


def _wrist_apart(sample, o, d, s, tc, h, i: int, k: int, cfg: ShaftEndConfig) -> float:
    """How far (colour distance, grey-level units) what follows step i on the band's
    mid-line lies from what is beside the band there (t_c +- ``outside`` h), on the nearer
    of the two sides; medians over the k samples after i. inf when nothing beside the
    band is in the image; 0 when what follows is coloured (saturation (max - min) / max
    of its BGR above ``max_saturation``): the wrist is bare metal."""
    j = slice(i + 1, min(len(s), i + k + 1))
    pts = _band_points(o, d, s[j], tc[j], h[j], (0.0, -cfg.outside, cfg.outside))   # (k, 3, 2)
    c = sample.colour(pts.reshape(-1, 2)).reshape(pts.shape[0], 3, -1)    # one read for the three rows

    def median_colour(r):
        cr = c[:, r]
        cr = cr[np.all(np.isfinite(cr), axis=1)]
        return np.median(cr, axis=0) if len(cr) else None

    after = median_colour(0)
    if after is not None and _saturation(after) > cfg.max_saturation:
        return 0.0                       # coloured: not the metal wrist
    sides = [m for m in (median_colour(1), median_colour(2)) if m is not None]
    if after is None or not sides:
        return np.inf
    return float(min(np.linalg.norm(after - m) for m in sides))


def _saturation(colour: np.ndarray) -> float:
    """(max - min) / max of a BGR colour; 0 for a grey image's single channel."""
    if len(colour) < 3:
        return 0.0
    return float(np.ptp(colour[:3]) / max(colour[:3].max(), 1.0))


def _centre_crossing(sample, o, d, s, tc, h, i: int, level: float, k: int, rows) -> float | None:
    """The median over the rows t_c + tau h (tau in ``rows``) of where each crosses
    ``level`` nearest sample i (within k samples), as a sample index; None if none does."""
    lo, hi = max(0, i - k), min(len(s), i + k + 1)
    taus = np.asarray(rows, float)
    if not len(taus):
        return None
    pts = _band_points(o, d, s[lo:hi], tc[lo:hi], h[lo:hi], taus)
    g = sample(pts.reshape(-1, 2)).reshape(hi - lo, len(taus))      # one read for all rows
    found = []
    for r in range(len(taus)):
        x = _crossing(g[:, r], i - lo, level, k)
        if x is not None:
            found.append(lo + x)
    return float(np.median(found)) if found else None


def locate(sample, lines: np.ndarray, segments: np.ndarray, distal: np.ndarray,
           config: ShaftEndConfig | None = None, predicted: np.ndarray | None = None) -> ShaftEnd | None:
    """The shaft's end (module doc). lines (2, 2) (rho, theta), segments (2, 4) the
    shaft edges' segments (undistorted full-size px); distal (2,): the image
    direction towards the wrist (any length); predicted (2,): where the estimate
    puts the end, or None. The profile spans ``search`` px either side of both the
    segments' distal end and the predicted end (a detector's segment may run on past
    the shaft's end along the narrower wrist's edges, or stop short of it under an
    occluder; by at most ``reach`` px). None if the band is degenerate or no step
    reaches the contrast."""
    cfg = config or ShaftEndConfig()
    lines = np.asarray(lines, float).reshape(-1, 2)
    segments = np.asarray(segments, float).reshape(-1, 4)
    if len(lines) != 2 or len(segments) != 2 or not np.all(np.isfinite(lines)):
        return None
    dirs = segments[:, 2:] - segments[:, :2]
    dirs = dirs / np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-9)
    distal = np.asarray(distal, float)
    dirs *= np.sign(dirs @ distal)[:, None] + (dirs @ distal == 0)
    d = dirs.sum(0)
    if not np.linalg.norm(d) > 1e-9:
        return None
    d /= np.linalg.norm(d)
    ends = segments.reshape(-1, 2)
    o = ends.mean(0)
    s_end = float(np.max((ends - o) @ d))          # the segments' distal end along d
    s_lo = s_hi = s_end
    if predicted is not None and np.all(np.isfinite(predicted)):
        s_pred = float(np.clip((np.asarray(predicted, float) - o) @ d, s_end - cfg.reach, s_end + cfg.reach))
        s_lo, s_hi = min(s_end, s_pred), max(s_end, s_pred)
    s = np.arange(s_lo - cfg.search, s_hi + cfg.search + 1e-9, cfg.step)
    tc, h = _band(lines, o, d, s)
    if tc is None or np.median(h) < cfg.min_half_width:
        return None
    pts = _band_points(o, d, s, tc, h, np.linspace(-cfg.width, cfg.width, cfg.samples))   # (S, T, 2)
    g = np.median(sample(pts.reshape(-1, 2)).reshape(pts.shape[:2]), axis=1)  # NaN off the image
    k = max(2, int(round(cfg.window * float(np.median(h)) / cfg.step)))
    before, after = _medians(g, k)
    D = after - before
    if not np.any(np.isfinite(D)):
        return None
    for i in _steps(D, cfg.min_contrast, cfg.rival):
        if D[i] < cfg.min_ratio * before[i]:     # a small step on a bright shaft: shading
            continue
        # the wrist, not the background or an occluder: what follows the step must differ
        # from what lies beside the band there
        if _wrist_apart(sample, o, d, s, tc, h, i, k, cfg) >= cfg.apart * D[i]:
            break
    else:
        return None
    x = _centre_crossing(sample, o, d, s, tc, h, i, 0.5 * (before[i] + after[i]), k, cfg.centre_rows)
    if x is None:
        return None
    j = int(np.clip(round(x), 0, len(s) - 1))
    sx = s[0] + x * cfg.step
    point = o + sx * d + tc[j] * np.array([-d[1], d[0]])
    return ShaftEnd(point, d, float(D[i]))
